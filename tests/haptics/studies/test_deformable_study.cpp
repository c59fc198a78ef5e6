// The thesis's displaced-bone study (paper VI) as a virtual experiment on deformable tissue
// (docs/algorithms.md sections 3, 5, 9 and 10), and AVCEC's closed-loop energy on that tissue.
//
// The scene: the bone phantom (a soft block over a bone slab tilted so that one side is closer
// to the surface, displacement -1 / 0 / +1) with 10 HU of seeded CT noise. Two tissues: the
// tool's (DeformableSetup's defaults, as `palp palpate --deformable` builds it: 5 mm cells, or
// 2.5 mm, the solver auto chooses, a 3 mm filter; the full studies) and, for the reduced study
// CI runs, the same voxelisation on 10 mm cells with a 5 mm filter on the whole-mesh explicit
// solver (726 nodes instead of 4851: a fraction of a millisecond per tick).
//
// The observer presses twice on each half of the block (x < 0, the patient's right, and x > 0;
// seeded hand-path noise: place, depth 3-4 mm, press time) and compares what it felt during the
// holds, left against right: the mean stiffness rendered (the rigid experiments' observer) and,
// as a second observer, the force over the hand's own depth (the stiffness the hand feels:
// tissue and coupling in series). Each observer has a 10 % Weber fraction and nothing tuned to
// the scene: a side that felt more than 10 % stiffer than the other is where the bone is closer;
// within 10 % it says level. A third observer adds Weber noise (palp::perception's model: each
// press perceived as ln(felt) + N(0, sigma^2), sigma giving a 10 % JND at 70.71 % in two
// intervals) before the same rule; it is reported, not asserted (a 3-way answer with a level
// class cannot reach 95 % under that noise unless the cue is several JNDs).
// Presses, not a lateral sweep: sweeping on this tissue the proxy lags the probe sideways
// (friction and the dimple's front slope) so much that the proxy-to-probe direction tilts
// ~50 degrees from the press axis and the rays mostly pass beside the bone: a 70 mm sweep
// observer's |log k ratio| was 0.03-0.08 for a displaced bone and up to 0.035 for a level one
// (bench/README.md).
#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <limits>
#include <map>
#include <memory>
#include <random>
#include <string>
#include <tuple>
#include <vector>

#include "palp/base/error.h"
#include "palp/haptics/devices/simulated_device.h"
#include "palp/haptics/devices/trajectory.h"
#include "palp/haptics/rendering/coupling_defaults.h"
#include "palp/haptics/session.h"
#include "palp/haptics/tissue/deformable_setup.h"
#include "palp/perception/observer.h"
#include "palp/studies/energy_budget.h"
#include "palp/studies/offline_run.h"
#include "palp/volume/phantom.h"

namespace palp::haptics {
namespace {

namespace geo = volume::phantom_geometry;

constexpr double kPeriod = 1e-3;
constexpr double kCell = 10e-3;  // FEM cell edge of the reduced study (the tool's default is 5 mm)
// The observers' Weber fraction: a difference under 10 % is not felt.
constexpr double kWeber = 0.10;

const DeviceSpec& touch() {
    const DeviceSpec* s = findDeviceSpec("3D Systems Touch");
    if (!s) throw ValueError("no 3D Systems Touch spec");
    return *s;
}

// The bone phantom (bone position @p displacement) at 1 mm voxels with 10 HU of noise (seed
// @p noiseSeed).
volume::Volume bonePhantom(int displacement, std::uint64_t noiseSeed) {
    volume::PhantomSpec spec;
    spec.params.scene = volume::PhantomScene::Bone;
    spec.params.displacement = displacement;
    spec.voxelSize = 1e-3;
    spec.noiseSigmaHu = 10;
    spec.seed = noiseSeed;
    return volume::makePhantomVolume(spec);
}

// The scene of @p vol with no iso-surface of its own: the proxy feels the FEM surface.
std::shared_ptr<Scene> boneScene(const volume::Volume& vol) {
    SceneOptions so;
    so.surfaceIso = std::numeric_limits<double>::quiet_NaN();
    return Scene::fromVolume(vol, so);
}

// The bone phantom with 10 HU noise (seed @p noiseSeed) as deformable tissue of mass damping
// @p alpha (1/s) and contact damping @p contactDamping (ratio of critical), cells of @p cell
// and a contact filter of width @p filter (m), cached.
std::shared_ptr<const Scene> boneTissue(int displacement, std::uint64_t noiseSeed,
                                        double alpha = 60, double contactDamping = 1,
                                        double cell = kCell, double filter = 5e-3) {
    static std::map<std::tuple<int, std::uint64_t, double, double, double, double>,
                    std::shared_ptr<const Scene>>
        cache;
    const auto key = std::make_tuple(displacement, noiseSeed, alpha, contactDamping, cell, filter);
    if (auto it = cache.find(key); it != cache.end()) return it->second;
    const volume::Volume vol = bonePhantom(displacement, noiseSeed);
    std::shared_ptr<Scene> scene = boneScene(vol);
    fem::VoxelizeOptions vo;
    vo.elementSize = cell;
    vo.tissueThreshold = -200;
    vo.boneThreshold = 500;
    fem::ElasticMaterial mat;
    mat.youngsModulus = 5e3;
    mat.poissonRatio = 0.45;
    mat.dampingAlpha = alpha;
    DeformableOptions dopt;
    dopt.filterWidth = filter;
    dopt.contactDampingRatio = contactDamping;
    scene->commit();
    scene->setDeformable(DeformableModel::fromVolume(vol, vo, mat, fem::BoxFace::yMax, dopt));
    cache.emplace(key, scene);
    return scene;
}

// The bone phantom with 10 HU noise (seed @p noiseSeed) as `palp palpate --deformable` makes
// its tissue (DeformableSetup's defaults, the press along +y so the support is the back face,
// the solver auto chooses; the regions, where chosen, inline every period as the tool's offline
// runs), cells of @p cell, cached. @p solver reports the choice.
std::shared_ptr<const Scene> toolTissue(int displacement, std::uint64_t noiseSeed, double cell,
                                        std::string* solver = nullptr) {
    static std::map<std::tuple<int, std::uint64_t, double>,
                    std::pair<std::shared_ptr<const Scene>, std::string>>
        cache;
    const auto key = std::make_tuple(displacement, noiseSeed, cell);
    auto it = cache.find(key);
    if (it == cache.end()) {
        const volume::Volume vol = bonePhantom(displacement, noiseSeed);
        std::shared_ptr<Scene> scene = boneScene(vol);
        DeformableSetup setup;
        setup.voxelize.elementSize = cell;
        setup.supportFace = faceOpposite(Eigen::Vector3d::UnitY());
        setup.setPeriod(kPeriod);
        setup.autoSolver = true;
        setup.options.regions.threaded = false;
        setup.options.regionsCentre = Eigen::Vector3d::Zero();  // the middle of the pressed face
        SolverChoice choice;
        scene->commit();
        scene->setDeformable(makeDeformableModel(vol, setup, &choice));
        it = cache.emplace(key, std::make_pair(scene, choice.reason)).first;
    }
    if (solver) *solver = it->second.second;
    return it->second.first;
}

SessionParams studyParams(CouplingMode mode) {
    SessionParams p;
    p.coupling = sceneCouplingDefaults(volume::PhantomScene::Bone);  // AVCEC, first hit 500 HU
    p.coupling.mode = mode;
    limitStiffnessToDevice(p.coupling, touch(), kPeriod);
    p.servo.periodSeconds = kPeriod;
    return p;
}

// The observers: 0 the stiffness rendered, 1 the force over the hand's depth (both with the
// Weber rule), 2 the stiffness rendered through Weber noise.
constexpr std::size_t kObservers = 3;
const char* const kObserverNames[kObservers] = {"stiffness", "force/depth", "noisy stiffness"};

struct Trial {
    int truth = 0;
    std::array<int, kObservers> pick{};         // per observer
    std::array<double, kObservers> logRatio{};  // per observer: log(left / right) as perceived
    // Per side: mean stiffness rendered, mean normal force over the hand's depth (N/m).
    std::array<double, 2> left{}, right{};
    double seconds = 0, maxForce = 0;
    bool finite = true;
    std::uint64_t clamped = 0;
};

// The Weber rule: the bone is closer on the side that felt more than kWeber stiffer.
int decide(double logRatio) {
    const double jnd = std::log1p(kWeber);
    if (logRatio > jnd) return +1;  // stiffer on the left (x > 0): bone closer there
    if (logRatio < -jnd) return -1;
    return 0;
}

// The study's tissue: the tool's on @p cell (> 0), the reduced study's 10 mm one otherwise.
std::shared_ptr<const Scene> studyTissue(int truth, std::uint64_t noiseSeed, double cell) {
    return cell > 0 ? toolTissue(truth, noiseSeed, cell) : boneTissue(truth, noiseSeed);
}

// One trial: bone position @p truth; two short presses on each half (x = -+(12..28) mm,
// z within +-10 mm, 3-4 mm deep, seeded), each on fresh tissue (a Session of its own).
Trial runTrial(std::uint64_t seed, int truth, std::uint64_t noiseSeed, CouplingMode mode,
               double cell) {
    std::mt19937_64 rng(seed);
    std::uniform_real_distribution<double> unit(0, 1);
    const auto jitter = [&](double a) { return a * (2 * unit(rng) - 1); };
    Trial out;
    out.truth = truth;
    const auto scene = studyTissue(truth, noiseSeed, cell);
    const SessionParams params = studyParams(mode);
    // The noisy observer's perception of each press (its own generator, seeded by the trial).
    std::mt19937_64 perceive(seed ^ 0x5eb5eb5eULL);
    std::normal_distribution<double> noise(0.0,
                                           perception::weberNoiseSd(kWeber, 0.70710678118654752));
    std::array<double, 2> kSum{}, fSum{}, n{}, perceivedLogK{};
    for (int press = 0; press < 4; ++press) {
        const std::size_t side = static_cast<std::size_t>(press % 2);  // 0: x < 0, 1: x > 0
        PressTrajectory p;
        const double approach = 0.005;
        p.start =
            Eigen::Vector3d((side ? 1 : -1) * (0.020 + jitter(0.008)), -approach, jitter(0.010));
        p.direction = Eigen::Vector3d(0, 1, 0);
        p.depthM = approach + 0.003 + 0.001 * unit(rng);
        p.pressSeconds = 0.25 + 0.1 * unit(rng);
        p.holdSeconds = 0.25;
        const double seconds = 2 * p.pressSeconds + p.holdSeconds;
        SimulatedDevice device(touch(), p, HandModel{}, kPeriod);
        Session session(scene, device, params);
        const auto ticks = static_cast<std::uint64_t>(std::ceil(seconds / kPeriod));
        double pressK = 0, pressN = 0;
        for (std::uint64_t i = 0; i < ticks; ++i) {
            const Snapshot& sn = session.step();
            out.finite = out.finite && sn.force.allFinite();
            out.maxForce = std::max(out.maxForce, sn.force.norm());
            out.clamped += sn.clamped ? 1 : 0;
            // What the hand feels while it holds the press.
            if (sn.contactCount == 0 || sn.timeSeconds < p.pressSeconds ||
                sn.timeSeconds > p.pressSeconds + p.holdSeconds)
                continue;
            kSum[side] += sn.stiffness;
            pressK += sn.stiffness;
            pressN += 1;
            // Force over the hand's own depth below the rest surface (y = 0): the stiffness the
            // hand feels, tissue and coupling in series.
            fSum[side] += -sn.force.y() / std::max(sn.probe.y(), 1e-4);
            n[side] += 1;
        }
        perceivedLogK[side] += 0.5 * (std::log(pressK / std::max(pressN, 1.0)) + noise(perceive));
        out.seconds += seconds;
    }
    for (std::size_t side = 0; side < 2; ++side) {
        const double m = std::max(n[side], 1.0);
        (side ? out.left : out.right) = {kSum[side] / m, fSum[side] / m};
    }
    out.logRatio = {std::log(out.left[0] / out.right[0]), std::log(out.left[1] / out.right[1]),
                    perceivedLogK[1] - perceivedLogK[0]};
    for (std::size_t o = 0; o < kObservers; ++o)
        out.pick[o] = std::isfinite(out.logRatio[o]) ? decide(out.logRatio[o]) : 0;
    return out;
}

struct StudyResult {
    int trials = 0;
    std::array<int, kObservers> correct{};
    // Per observer, truth (-1 / 0 / +1) x pick (-1 / 0 / +1).
    std::array<std::array<std::array<int, 3>, 3>, kObservers> confusion{};
    double simulatedSeconds = 0, wallSeconds = 0, maxForce = 0;
    std::uint64_t clamped = 0;
    bool finite = true;
};

// @p perClass trials of each bone position (seeds 0x57d90000 + trial; noise seed trial % 4) on
// the tissue of @p cell (studyTissue()).
StudyResult runStudy(int perClass, CouplingMode mode, bool print, double cell = 0) {
    StudyResult r;
    std::string solver = "whole mesh, 10 mm cells";
    if (cell > 0) toolTissue(0, 0, cell, &solver);
    const auto t0 = std::chrono::steady_clock::now();
    for (int t = 0; t < 3 * perClass; ++t) {
        const int truth = t % 3 - 1;
        const Trial a = runTrial(0x57d90000u + static_cast<std::uint64_t>(t), truth,
                                 static_cast<std::uint64_t>(t % 4), mode, cell);
        ++r.trials;
        for (std::size_t o = 0; o < kObservers; ++o) {
            r.correct[o] += a.pick[o] == truth ? 1 : 0;
            ++r.confusion[o][static_cast<std::size_t>(truth + 1)]
                         [static_cast<std::size_t>(a.pick[o] + 1)];
        }
        r.simulatedSeconds += a.seconds;
        r.maxForce = std::max(r.maxForce, a.maxForce);
        r.clamped += a.clamped;
        r.finite = r.finite && a.finite;
        if (print)
            std::printf(
                "%-5s trial %3d: bone %+d; k right/left %4.0f/%4.0f N/m (log %+.3f) -> %+d; "
                "F/depth right/left %.0f/%.0f N/m (log %+.3f) -> %+d; noisy k (log %+.3f) -> "
                "%+d\n",
                couplingModeName(mode), t, truth, a.right[0], a.left[0], a.logRatio[0], a.pick[0],
                a.right[1], a.left[1], a.logRatio[1], a.pick[1], a.logRatio[2], a.pick[2]);
    }
    r.wallSeconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    std::printf("displaced-bone study, %s + FEM (%s; %d trials, 3 bone positions, Weber %.0f %%):",
                couplingModeName(mode), solver.c_str(), r.trials, 100 * kWeber);
    for (std::size_t o = 0; o < kObservers; ++o) {
        std::printf(" %s %d/%d (%.1f %%; picks -1/0/+1 by truth:", kObserverNames[o], r.correct[o],
                    r.trials, 100.0 * r.correct[o] / r.trials);
        for (const auto& row : r.confusion[o]) std::printf(" %d/%d/%d", row[0], row[1], row[2]);
        std::printf(")%s", o + 1 < kObservers ? ";" : "\n");
    }
    std::printf(
        "  mean trial %.2f s simulated, %.2f s wall; max force %.3f N, %llu clamped ticks\n",
        r.simulatedSeconds / r.trials, r.wallSeconds / r.trials, r.maxForce,
        static_cast<unsigned long long>(r.clamped));
    return r;
}

// The reduced study (3 x 8 trials, 10 mm cells): AVCEC on FEM tissue finds the bone.
TEST(DisplacedBoneStudy, AvcecOnFemTissueFindsTheCloserSide) {
    const StudyResult ec = runStudy(8, CouplingMode::AVCEC, true);
    EXPECT_GE(ec.correct[0], 22);  // >= 90 % of 24
    EXPECT_TRUE(ec.finite);
    EXPECT_EQ(ec.clamped, 0u);
    EXPECT_LE(ec.maxForce, touch().maxForceN + 1e-9);
}

// The full study on the tool's tissue (3 x 40 trials per coupling), 5 mm cells (the tool's
// default) and 2.5 mm: figures in bench/README.md.
void fullStudy(double cell) {
    const StudyResult ec = runStudy(40, CouplingMode::AVCEC, true, cell);
    const StudyResult vc = runStudy(40, CouplingMode::VC, true, cell);
    EXPECT_GE(ec.correct[0], 114);  // >= 95 % of 120
    EXPECT_TRUE(ec.finite && vc.finite);
    EXPECT_EQ(ec.clamped, 0u);
}
TEST(DisplacedBoneStudy, DISABLED_FullFiveMillimetreCells) { fullStudy(5e-3); }
TEST(DisplacedBoneStudy, DISABLED_FullTwoAndAHalfMillimetreCells) { fullStudy(2.5e-3); }

// ---------------------------------------------------------------------------------------------
// Closed loops of the hand on deformable tissue

struct LoopResult {
    EnergyBudget budget;
    std::vector<double> loopWork;  // hand work per loop, J
    double maxForce = 0, minStiffness = INFINITY, maxStiffness = 0;
    std::uint64_t clamped = 0;
    bool finite = true;
};

constexpr int kLoops = 6;

// Frictionless circles (3 mm radius, 4 mm deep, 1 Hz) around @p centre on the bone phantom's
// tissue (displacement -1: the bone is closest at its right edge, x = -40 mm).
LoopResult runLoops(const Eigen::Vector3d& centre, CouplingMode mode, double alpha,
                    double contactDamping) {
    SessionParams sp = studyParams(mode);
    sp.proxy.staticFriction = 0;
    sp.proxy.dynamicFriction = 0;
    CircleTrajectory path;
    path.centre = centre;
    path.radiusM = 0.003;
    path.frequencyHz = 1;
    path.depthM = 0.004;
    SimulatedDevice device(touch(), path, HandModel{}, kPeriod);
    Session session(boneTissue(-1, 0, alpha, contactDamping), device, sp);
    const double start = path.approachSeconds + path.rampSeconds;
    const auto ticks = static_cast<std::uint64_t>(std::ceil((start + kLoops) / kPeriod));
    LoopResult r;
    std::vector<Snapshot> snaps;
    snaps.reserve(ticks);
    for (std::uint64_t i = 0; i < ticks; ++i) {
        snaps.push_back(session.step());
        const Snapshot& s = snaps.back();
        r.finite = r.finite && s.force.allFinite();
        r.maxForce = std::max(r.maxForce, s.force.norm());
        r.clamped += s.clamped ? 1 : 0;
        if (s.timeSeconds >= start && s.contactCount > 0) {
            r.minStiffness = std::min(r.minStiffness, s.stiffness);
            r.maxStiffness = std::max(r.maxStiffness, s.stiffness);
        }
    }
    r.budget = energyBudget(snaps, start);
    // Loop by loop (the circle turns at exactly 1 Hz after the ramp).
    for (int l = 0; l < kLoops; ++l) {
        std::vector<Snapshot> one;
        for (const Snapshot& s : snaps)
            if (s.timeSeconds >= start + l - 1e-9 && s.timeSeconds <= start + l + 1 + 1e-9)
                one.push_back(s);
        r.loopWork.push_back(energyBudget(one, start + l).handWork);
    }
    return r;
}

double positiveSum(const std::vector<double>& v) {
    double s = 0;
    for (double x : v) s += std::max(x, 0.0);
    return s;
}

// Circles over the bone's right edge (x = -40 mm; the slab's top at 18 mm there) and over its
// slope halfway (x = -20 mm), on the study's tissue (alpha 60/s, critical contact damping) and
// on a nearly undamped one (alpha 2/s, contact damping 0.1 of critical), where the tissue
// takes less of what the coupling gives. The measure (as test_energy_loop): the hand work of
// each loop, and the sum of the positive ones.
TEST(DeformableEnergyLoop, AvcecGivesTheHandNoEnergyOverTheBoneEdgeAndSlope) {
    struct Tissue {
        const char* name;
        double alpha, contactDamping;
    };
    for (const Tissue& tissue :
         {Tissue{"alpha 60/s, contact 1.0", 60, 1.0}, Tissue{"alpha 2/s, contact 0.1", 2, 0.1}}) {
        for (const Eigen::Vector3d& centre :
             {Eigen::Vector3d(-0.040, 0, 0.0), Eigen::Vector3d(-0.020, 0, 0.0)}) {
            std::array<LoopResult, 3> r;
            const std::array<CouplingMode, 3> modes{CouplingMode::VC, CouplingMode::AVC,
                                                    CouplingMode::AVCEC};
            for (std::size_t m = 0; m < 3; ++m)
                r[m] = runLoops(centre, modes[m], tissue.alpha, tissue.contactDamping);
            std::printf("tissue %s, circles at x = %.0f mm (%d loops, frictionless):\n",
                        tissue.name, centre.x() * 1e3, kLoops);
            for (std::size_t m = 0; m < 3; ++m) {
                std::printf("  %-5s hand work %+.4f mJ, positive loop sum %.4f mJ; per loop (mJ):",
                            couplingModeName(modes[m]), r[m].budget.handWork * 1e3,
                            positiveSum(r[m].loopWork) * 1e3);
                for (double w : r[m].loopWork) std::printf(" %+.4f", w * 1e3);
                std::printf("; k %.0f-%.0f N/m, max force %.3f N\n", r[m].minStiffness,
                            r[m].maxStiffness, r[m].maxForce);
                EXPECT_TRUE(r[m].finite) << couplingModeName(modes[m]);
                EXPECT_EQ(r[m].clamped, 0u) << couplingModeName(modes[m]);
                EXPECT_LE(r[m].maxForce, touch().maxForceN + 1e-9);
            }
            // AVCEC gives the hand at most 5 % of AVC's positive loop work (1 uJ when AVC
            // gives none), loop by loop as in all.
            const double avcPositive = positiveSum(r[1].loopWork);
            EXPECT_LE(positiveSum(r[2].loopWork), std::max(0.05 * avcPositive, 1e-6))
                << tissue.name << " x " << centre.x();
        }
    }
}

// A steady press held over the bone at the tool's 5 mm cells, 9 mm deep (as `palp palpate
// --phantom bone --deformable --trajectory press --depth 9 --hold 2`, on the study's tissue): the
// tissue carries the proxy, so AVCEC's k (where the proxy sits) and the force that dents the
// tissue form a loop. With the material frame constant per facet (before 2026-11-29) the loop
// alternated every tick without k's time filter (a 500 Hz buzz): the mean tick-to-tick change of
// |F| over the last 0.8 s of the hold was 27 % of its mean unfiltered, 2.2 % with the default
// 5 ms. With the frame continuous across facets (DeformableBody::anchorRotation) the press is
// steady with or without the filter (0.1 % each); the filter stays for bone under a thin layer
// (the head CT, docs/algorithms.md section 10) and must keep the force the tissue gives.
TEST(DeformableHold, AvcecHeldPressIsSteadyWithAndWithoutKsTimeFilter) {
    auto buzz = [](double tau) {
        SessionParams sp = studyParams(CouplingMode::AVCEC);
        sp.coupling.stiffnessTimeConstant = tau;
        PressTrajectory p;
        p.start = Eigen::Vector3d(0, -0.005, 0);
        p.direction = Eigen::Vector3d(0, 1, 0);
        p.depthM = 0.014;  // 9 mm below the rest surface
        p.pressSeconds = 0.5;
        p.holdSeconds = 1.5;
        SimulatedDevice device(touch(), p, HandModel{}, kPeriod);
        Session session(boneTissue(0, 0, 60, 1, 5e-3), device, sp);
        double sum = 0, change = 0, last = NAN, peak = 0;
        int n = 0;
        for (int i = 0; i < 2000; ++i) {
            const Snapshot& s = session.step();
            const double f = s.force.norm();
            peak = std::max(peak, f);
            if (s.timeSeconds < 1.2) continue;
            if (std::isfinite(last)) change += std::abs(f - last);
            sum += f;
            last = f;
            ++n;
        }
        std::printf(
            "tau %.0f ms: held force %.4f N, mean tick-to-tick change %.4f N (%.1f %%), "
            "peak %.3f N\n",
            tau * 1e3, sum / n, change / (n - 1), 100 * change / (n - 1) / (sum / n), peak);
        return std::array<double, 2>{sum / n, change / (n - 1)};
    };
    const auto off = buzz(0), on = buzz(SessionParams{}.coupling.stiffnessTimeConstant);
    EXPECT_GT(on[0], 0.1);  // the press is felt
    // Within 10 % of the unfiltered mean: the filter keeps the force the tissue gives.
    EXPECT_NEAR(on[0], off[0], 0.1 * off[0]);
    EXPECT_LT(off[1], 0.01 * off[0]);
    EXPECT_LT(on[1], 0.01 * on[0]);
}

// Held presses over the bone with the tool's 5 mm cells and 3 mm contact filter, 3, 6 and 9 mm
// deep, AVC and AVCEC: the force vector the hand feels must be steady. At the bottom of the press
// the proxy sits at the surface vertex under the probe and changes facet every tick; with a
// material frame constant per facet (it jumped there by twice the facets' tilt) AVCEC's rays
// flipped sides, its spherical term flipped sign and its reaction pushed the proxy back across the
// vertex: a period-4 cycle, the force vector turning by 55 % of |F| a tick at 9 mm (25 % at 3 mm),
// a 250-500 Hz buzz. With the frame continuous, AVC and AVCEC still changed by 1.3 % (6 mm) and
// 2.7-3.1 % (9 mm) a tick: the proxy's height hopped by up to 8 um between triples of the pit's
// facets, which the proxy's potential rule (Proxy::update, step 7) holds. Measured over the last
// second of the hold: the mean tick-to-tick change of the force vector over the mean |F|, and the
// share of the force's energy (the three components' squared DFT, the mean included) above 50 Hz;
// both below 1 %.
TEST(DeformableHold, HeldPressesGiveASteadyForceVector) {
    for (CouplingMode mode : {CouplingMode::AVC, CouplingMode::AVCEC}) {
        for (double depth : {3e-3, 6e-3, 9e-3}) {
            const SessionParams sp = studyParams(mode);
            PressTrajectory p;
            p.start = Eigen::Vector3d(0, -0.005, 0);
            p.direction = Eigen::Vector3d(0, 1, 0);
            p.depthM = 0.005 + depth;
            p.pressSeconds = 0.5;
            p.holdSeconds = 1.5;
            SimulatedDevice device(touch(), p, HandModel{}, kPeriod);
            Session session(boneTissue(0, 0, 60, 1, 5e-3, 3e-3), device, sp);
            std::vector<Eigen::Vector3d> held;
            for (int i = 0; i < 2000; ++i) {
                const Snapshot& s = session.step();
                if (s.timeSeconds >= 1.0) held.push_back(s.force);
            }
            double magnitude = 0, change = 0;
            for (std::size_t i = 0; i < held.size(); ++i) {
                magnitude += held[i].norm() / static_cast<double>(held.size());
                if (i > 0) change += (held[i] - held[i - 1]).norm();
            }
            change /= static_cast<double>(held.size() - 1);
            // The DFT's energy per bin, summed over the components; the share above 50 Hz.
            const auto n = static_cast<int>(held.size());
            double total = 0, above = 0;
            for (int f = 0; f <= n / 2; ++f) {
                Eigen::Vector3d re = Eigen::Vector3d::Zero(), im = Eigen::Vector3d::Zero();
                for (int i = 0; i < n; ++i) {
                    const double a = 2 * 3.14159265358979 * f * i / n;
                    re += std::cos(a) * held[static_cast<std::size_t>(i)];
                    im -= std::sin(a) * held[static_cast<std::size_t>(i)];
                }
                const double e =
                    (f == 0 || 2 * f == n ? 1.0 : 2.0) * (re.squaredNorm() + im.squaredNorm());
                total += e;
                if (f / (n * kPeriod) > 50) above += e;
            }
            std::printf(
                "%-5s held %.0f mm: |F| %.4f N, force vector change %.3f %% a tick, %.4f %% of "
                "the energy above 50 Hz\n",
                couplingModeName(mode), depth * 1e3, magnitude, 100 * change / magnitude,
                100 * above / total);
            EXPECT_GT(magnitude, 0.05) << couplingModeName(mode) << " " << depth;
            EXPECT_LT(change, 0.01 * magnitude) << couplingModeName(mode) << " " << depth;
            EXPECT_LT(above, 0.01 * total) << couplingModeName(mode) << " " << depth;
        }
    }
}

}  // namespace
}  // namespace palp::haptics
