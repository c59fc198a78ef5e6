// palp palpate: palpate a scan or a thesis phantom with VC/AVC/AVCEC along a scripted path
// (simulated hand and device), offline as fast as possible or on the real-time servo loop;
// writes a CSV trace and a PNG map over the palpated plane.
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <limits>
#include <memory>
#include <nlohmann/json.hpp>
#include <string>
#include <thread>
#include <vector>

#include "commands.h"
#include "palp/base/error.h"
#include "palp/haptics/coupling_defaults.h"
#include "palp/haptics/map_png.h"
#include "palp/haptics/offline_run.h"
#include "palp/haptics/scalar_map.h"
#include "palp/haptics/session.h"
#include "palp/haptics/simulated_device.h"
#include "palp/haptics/trace_csv.h"
#include "palp/haptics/trajectory.h"
#include "palp/volume/load.h"
#include "palp/volume/phantom.h"

namespace palp::tool {

namespace fs = std::filesystem;
using nlohmann::json;

namespace {

std::string fmt(double x) {
    char b[64];
    std::snprintf(b, sizeof b, "%g", x);
    return b;
}

int axisIndex(const Eigen::Vector3d& a) {
    int i = 0;
    a.cwiseAbs().maxCoeff(&i);
    return i;
}

std::string axisName(const Eigen::Vector3d& a) {
    const int i = axisIndex(a);
    return std::string(a[i] < 0 ? "-" : "+") + "xyz"[i];
}

void requirePositive(double value, const char* option, const char* unit) {
    if (!(value > 0) || !std::isfinite(value)) {
        throw ValueError(std::string(option) + ": expected a positive number of " + unit +
                         ", found " + fmt(value));
    }
}

haptics::CouplingMode parseMode(const std::string& s) {
    if (s == "vc") return haptics::CouplingMode::VC;
    if (s == "avc") return haptics::CouplingMode::AVC;
    if (s == "avcec") return haptics::CouplingMode::AVCEC;
    throw ValueError("--mode: expected vc, avc or avcec, found '" + s + "'");
}

haptics::RaySource parseSource(const std::string& s) {
    if (s == "mesh") return haptics::RaySource::Mesh;
    if (s == "first-hit") return haptics::RaySource::VolumeFirstHit;
    if (s == "accumulate") return haptics::RaySource::VolumeAccumulate;
    throw ValueError("--source: expected mesh, first-hit or accumulate, found '" + s + "'");
}

}  // namespace

Eigen::Vector3d parseAxis(const std::string& text, const char* option) {
    std::string s = text;
    double sign = 1;
    if (!s.empty() && (s[0] == '+' || s[0] == '-')) {
        sign = s[0] == '-' ? -1 : 1;
        s = s.substr(1);
    }
    if (s == "x") return sign * Eigen::Vector3d::UnitX();
    if (s == "y") return sign * Eigen::Vector3d::UnitY();
    if (s == "z") return sign * Eigen::Vector3d::UnitZ();
    throw ValueError(std::string(option) + ": expected an axis +x, -x, +y, -y, +z or -z, found '" +
                     text + "'");
}

Command addPalpate(CLI::App& root) {
    struct Args {
        std::string file;
        std::string phantom;
        int quadrant = 0;
        std::string shape = "circle";
        int displacement = 0;
        std::string profile = "linear";
        double voxelMm = 1;
        double noiseHu = 0;
        std::uint64_t seed = 0;
        std::string mode, source;
        double kBase = NAN, kMax = NAN, lMaxMm = NAN, lRefMm = NAN, mMax = NAN;
        double threshold = NAN, sigmaPerMm = NAN, sigmaThreshold = NAN, tauStop = NAN;
        double stepMm = NAN, damping = NAN;
        int ring = -1;
        double surfaceIso = -500;
        double muStatic = 0.5, muDynamic = 0.3;
        bool passivityControl = false;
        std::string trajectory = "raster";
        std::vector<double> centreMm;
        std::vector<double> extentMm;
        double spacingMm = 2;
        double speedMmps = NAN;
        double depthMm = 4;
        std::string pressAxis = "+y";
        std::string sweepAxis;
        double radiusMm = 10;
        double frequencyHz = 1;
        int passes = 4;
        double holdSeconds = 0.5;
        bool realtime = false;
        bool fast = false;
        double seconds = 0;
        std::string trace;
        std::string map;
        std::string mapQuantity = "stiffness";
        std::string mapAt = "proxy";
        double mapPixelMm = 0;
        bool grey = false;
        std::string device = "3D Systems Touch";
        bool json = false;
        bool deformable = false;
        double femCellMm = 5;
        double youngKpa = 5;
        double poisson = 0.45;
        double femAlpha = 60;
        double femBeta = 0;
        double filterMm = 3;
        double boneHu = 500;
        double tissueHu = -200;
        std::string femSolver = "explicit";
        int primaryNodes = 60;
        double secondaryHz = 100;
        int lod = 1;
    };
    auto args = std::make_shared<Args>();
    CLI::App* app = root.add_subcommand(
        "palpate",
        "Palpate a volume or a thesis phantom with VC/AVC/AVCEC along a scripted path (simulated "
        "hand and device); write a CSV trace and a PNG map");
    app->add_option("file", args->file, "Volume to palpate (.vdb or any scan palp reads)");
    app->add_option("--phantom", args->phantom, "Built-in scene instead of a file")
        ->check(CLI::IsMember({"avc", "avcec", "bone", "stiffness"}));
    CLI::Option* quadrantOpt =
        app->add_option("--quadrant", args->quadrant, "avc: quadrant of the hidden box, 0-3")
            ->check(CLI::Range(0, 3));
    CLI::Option* shapeOpt =
        app->add_option("--shape", args->shape, "avcec: plate outline")
            ->check(CLI::IsMember({"circle", "triangle", "rectangle", "hexagon", "pentagon"}));
    CLI::Option* displacementOpt =
        app->add_option("--displacement", args->displacement, "bone: -1, 0 or 1")
            ->check(CLI::Range(-1, 1));
    CLI::Option* profileOpt =
        app->add_option("--profile", args->profile, "stiffness: CL transition profile")
            ->check(CLI::IsMember({"linear", "cosine", "tanh"}));
    CLI::Option* voxelOpt =
        app->add_option("--voxel-mm", args->voxelMm, "Phantom voxel edge, mm (default 1)");
    CLI::Option* noiseOpt =
        app->add_option("--noise", args->noiseHu, "Phantom noise standard deviation, HU");
    CLI::Option* seedOpt = app->add_option("--seed", args->seed, "Phantom noise seed");
    CLI::Option* deformableOpt = app->add_flag(
        "--deformable", args->deformable,
        "Deformable tissue: voxelised hexahedral FEM (fixed on the face opposite the press and "
        "inside bone), VC only, the coupling force spread by a Gaussian filter");
    std::vector<CLI::Option*> femOpts = {
        app->add_option("--fem-cell-mm", args->femCellMm, "deformable: element edge, mm (5)"),
        app->add_option("--young-kpa", args->youngKpa, "deformable: Young's modulus, kPa (5)"),
        app->add_option("--poisson", args->poisson, "deformable: Poisson's ratio (0.45)"),
        app->add_option("--fem-damping", args->femAlpha,
                        "deformable: mass-proportional damping alpha, 1/s (60)"),
        app->add_option("--fem-beta", args->femBeta,
                        "deformable: stiffness-proportional damping beta, s (0)"),
        app->add_option("--filter-mm", args->filterMm,
                        "deformable: Gaussian filter width sigma, mm (3; 0 = nearest node)"),
        app->add_option("--bone-hu", args->boneHu,
                        "deformable: cells above this are bone, their nodes fixed (500 HU)"),
        app->add_option("--tissue-hu", args->tissueHu,
                        "deformable: cells above this are tissue (-200 HU)"),
        app->add_option("--fem-solver", args->femSolver,
                        "deformable: 'explicit' (whole mesh every tick, default) or 'regions' "
                        "(asynchronous regions: explicit primary around the contact, implicit "
                        "secondary; threaded with --realtime; with --fast synchronous and slow, "
                        "since every contact move rebuilds the layout inline)")
            ->check(CLI::IsMember({"explicit", "regions"})),
        app->add_option("--primary-nodes", args->primaryNodes,
                        "regions: seed nodes of the primary region (60)")
            ->check(CLI::Range(1, 100000)),
        app->add_option("--secondary-hz", args->secondaryHz,
                        "regions: secondary solve rate, Hz (100)")
            ->check(CLI::Range(1.0, 1000.0)),
        app->add_option("--lod", args->lod, "regions: secondary level of detail, 1, 2 or 4 (1)")
            ->check(CLI::IsMember({1, 2, 4}))};
    app->add_option("--mode", args->mode, "Coupling: vc, avc or avcec (default per scene)");
    app->add_option("--source", args->source,
                    "Ray source: mesh, first-hit or accumulate (default per scene)");
    app->add_option("--k-base", args->kBase, "Surface stiffness k_s, N/m (default 300)");
    app->add_option("--k-max", args->kMax,
                    "Stiffness clamp k_max, N/m (default 2400, lowered to the device's limit)");
    app->add_option("--l-max", args->lMaxMm, "Ray length L_max, mm (default 40)");
    app->add_option("--l-ref", args->lRefMm,
                    "L_ref of m(L) = clamp(L_ref / L, 1, m_max), mm (default per scene)");
    app->add_option("--m-max", args->mMax, "Largest stiffness multiplier m_max (default 8)");
    app->add_option("--threshold", args->threshold,
                    "first-hit and mesh: hard-structure value, HU (default per scene)");
    app->add_option("--sigma", args->sigmaPerMm,
                    "accumulate: hardness above --sigma-threshold, 1/mm (default 1)");
    app->add_option("--sigma-threshold", args->sigmaThreshold,
                    "accumulate: value from which sigma applies, HU (default 500)");
    app->add_option("--tau-stop", args->tauStop, "accumulate: tau_stop (default 3)");
    app->add_option("--step", args->stepMm, "Ray sample spacing, mm (default 0.5)");
    app->add_option("--ring", args->ring, "Low-pass ring rays (default 0)");
    app->add_option("--damping", args->damping, "Coupling damping b, N s/m (default 0)");
    app->add_option("--surface-iso", args->surfaceIso,
                    "Value of the surface the proxy slides on (default -500 HU)");
    app->add_option("--mu-static", args->muStatic, "Static friction (default 0.5)");
    app->add_option("--mu-dynamic", args->muDynamic, "Dynamic friction (default 0.3)");
    app->add_flag("--passivity-control", args->passivityControl,
                  "Add the passivity controller (the observer always runs)");
    app->add_option("--trajectory", args->trajectory, "Path: raster, sweep, circle or press")
        ->check(CLI::IsMember({"raster", "sweep", "circle", "press"}));
    app->add_option("--centre", args->centreMm,
                    "Centre x,y,z of the path on the surface, mm (default: the middle of the "
                    "volume's lateral box, on its face against the press axis)")
        ->delimiter(',')
        ->expected(3);
    app->add_option("--extent", args->extentMm,
                    "Raster U,V size (sweep: U is the length), mm (default: the volume's lateral "
                    "box less 5 mm each side)")
        ->delimiter(',')
        ->expected(1, 2);
    app->add_option("--spacing", args->spacingMm, "Raster line spacing, mm (default 2)");
    app->add_option("--speed", args->speedMmps,
                    "Speed along the path, mm/s (default 100 raster, 50 sweep)");
    app->add_option("--depth", args->depthMm, "Press depth of the target below the surface, mm");
    app->add_option("--press-axis", args->pressAxis,
                    "Press direction into the body (default +y: anterior to posterior)");
    app->add_option("--sweep-axis", args->sweepAxis,
                    "Sweep direction / raster u axis (default: the first lateral axis)");
    app->add_option("--radius", args->radiusMm, "circle: radius, mm");
    app->add_option("--frequency", args->frequencyHz, "circle: revolutions per second");
    app->add_option("--passes", args->passes,
                    "sweep: passes (direction changes + 1); circle: turns")
        ->check(CLI::Range(1, 1000));
    app->add_option("--hold", args->holdSeconds, "press: hold time, s");
    auto* rt = app->add_flag("--realtime", args->realtime,
                             "Run on the 1 kHz servo thread (wall-clock time)");
    auto* fast = app->add_flag("--fast", args->fast, "Step offline as fast as possible (default)");
    rt->excludes(fast);
    app->add_option("--seconds", args->seconds,
                    "Simulated time, s (default: until the path is done)");
    app->add_option("--trace", args->trace, "Write a CSV trace of every tick");
    app->add_option("--map", args->map, "Write a PNG map over the palpated plane");
    app->add_option("--map-quantity", args->mapQuantity, "stiffness, force or energy")
        ->check(CLI::IsMember({"stiffness", "force", "energy"}));
    app->add_option("--map-at", args->mapAt,
                    "Bin at the proxy (what the hand feels where it is) or at the centre ray's "
                    "end (where the structure that set k lies)")
        ->check(CLI::IsMember({"proxy", "ray-end"}));
    app->add_option("--map-pixel", args->mapPixelMm, "Map pixel edge, mm (default: --spacing)");
    app->add_flag("--grey", args->grey, "Grey map instead of black-red-yellow-white");
    app->add_option("--device", args->device, "Device class whose limits apply");
    app->add_flag("--json", args->json, "Print the figures as JSON");

    return {
        app,
        [args, quadrantOpt, shapeOpt, displacementOpt, profileOpt, voxelOpt, noiseOpt, seedOpt,
         deformableOpt, femOpts]() -> int {
            const Args& a = *args;
            if (a.file.empty() == a.phantom.empty()) {
                throw ValueError("palpate: expected a FILE or --phantom SCENE, found " +
                                 std::string(a.file.empty() ? "neither" : "both"));
            }
            // Scene options apply to one phantom each; say so instead of ignoring them.
            const struct {
                CLI::Option* option;
                const char* scene;  // nullptr: any phantom
            } sceneOpts[] = {{quadrantOpt, "avc"},      {shapeOpt, "avcec"},
                             {displacementOpt, "bone"}, {profileOpt, "stiffness"},
                             {voxelOpt, nullptr},       {noiseOpt, nullptr},
                             {seedOpt, nullptr}};
            for (const auto& so : sceneOpts) {
                if (so.option->count() == 0) continue;
                const std::string what =
                    so.scene ? "--phantom " + std::string(so.scene) : "--phantom";
                if (a.phantom.empty()) {
                    throw ValueError(so.option->get_name() + ": expected " + what +
                                     " (a phantom scene option), found a FILE '" + a.file + "'");
                }
                if (so.scene && a.phantom != so.scene) {
                    throw ValueError(so.option->get_name() + ": expected " + what +
                                     ", found --phantom " + a.phantom);
                }
            }
            if (!a.deformable) {
                for (CLI::Option* o : femOpts) {
                    if (o->count() > 0)
                        throw ValueError(o->get_name() +
                                         ": expected --deformable, found a rigid "
                                         "scene");
                }
            }
            (void)deformableOpt;
            const haptics::DeviceSpec* spec = haptics::findDeviceSpec(a.device);
            if (!spec) {
                std::string names;
                for (const auto& s : haptics::deviceSpecs())
                    names += (names.empty() ? "'" : ", '") + std::string(s.name) + "'";
                throw ValueError("--device: expected one of " + names + ", found '" + a.device +
                                 "'");
            }
            for (const std::string* out : {&a.trace, &a.map}) {
                if (out->empty()) continue;
                const fs::path path(*out);
                const fs::path dir = path.has_parent_path() ? path.parent_path() : fs::path(".");
                std::error_code ec;
                if (!fs::is_directory(dir, ec)) {
                    throw IoError(path.string() + ": expected an existing directory '" +
                                  dir.string() + "' for the output, found none");
                }
            }
            requirePositive(a.depthMm, "--depth", "mm");
            requirePositive(a.spacingMm, "--spacing", "mm");
            if (a.seconds < 0 || !std::isfinite(a.seconds))
                throw ValueError("--seconds: expected >= 0, found " + fmt(a.seconds));

            // Volume and default coupling.
            volume::Volume vol;
            haptics::CouplingParams cp;
            std::string label;
            if (!a.phantom.empty()) {
                requirePositive(a.voxelMm, "--voxel-mm", "mm");
                volume::PhantomSpec ps;
                ps.params.scene = volume::parseScene(a.phantom);
                ps.params.quadrant = a.quadrant;
                ps.params.shape = volume::parseShape(a.shape);
                ps.params.displacement = a.displacement;
                ps.params.profile = volume::parseProfile(a.profile);
                ps.voxelSize = a.voxelMm * 1e-3;
                ps.noiseSigmaHu = a.noiseHu;
                ps.seed = a.seed;
                vol = volume::makePhantomVolume(ps);
                cp = haptics::sceneCouplingDefaults(ps.params.scene);
                label = volume::Phantom(ps.params).description();
            } else {
                vol = volume::load({fs::path(a.file)});
                cp = haptics::scanCouplingDefaults();
                label = a.file;
            }
            if (!a.mode.empty()) cp.mode = parseMode(a.mode);
            if (a.deformable) {
                if (!a.mode.empty() && cp.mode != haptics::CouplingMode::VC) {
                    throw ValueError(
                        "--mode: expected vc with --deformable (AVC/AVCEC on "
                        "deformable tissue are not built yet), found '" +
                        a.mode + "'");
                }
                cp.mode = haptics::CouplingMode::VC;
                // Explicit tissue coupling is stable for k below the tissue's local stiffness
                // (deformable.h): a softer default than the rigid scenes' 300 N/m.
                // On the asynchronous regions the loop also sees the quasi-static secondary's
                // compliance one period late while a new layout is prepared: 100 N/m oscillates
                // on the bone phantom there, 50 N/m does not (bench/README.md).
                if (!std::isfinite(a.kBase)) cp.baseStiffness = a.femSolver == "regions" ? 50 : 100;
            }
            if (!a.source.empty()) cp.source = parseSource(a.source);
            if (std::isfinite(a.kBase)) cp.baseStiffness = a.kBase;
            if (std::isfinite(a.kMax)) cp.maxStiffness = a.kMax;
            if (std::isfinite(a.lMaxMm)) cp.bundle.length = a.lMaxMm * 1e-3;
            if (std::isfinite(a.lRefMm)) cp.referenceLength = a.lRefMm * 1e-3;
            if (std::isfinite(a.mMax)) cp.maxMultiplier = a.mMax;
            if (std::isfinite(a.threshold)) cp.firstHit.threshold = static_cast<float>(a.threshold);
            if (std::isfinite(a.sigmaPerMm) || std::isfinite(a.sigmaThreshold)) {
                const double s = std::isfinite(a.sigmaPerMm) ? a.sigmaPerMm : 1.0;
                const double t = std::isfinite(a.sigmaThreshold) ? a.sigmaThreshold : 500.0;
                requirePositive(s, "--sigma", "1/mm");
                cp.accumulate.sigma = kernels::TransferFunction::step(static_cast<float>(t),
                                                                      static_cast<float>(s * 1e3));
            }
            if (std::isfinite(a.tauStop)) cp.accumulate.tauStop = a.tauStop;
            if (std::isfinite(a.stepMm)) {
                cp.firstHit.step = a.stepMm * 1e-3;
                cp.accumulate.step = a.stepMm * 1e-3;
            }
            if (a.ring >= 0) cp.bundle.ringCount = a.ring;
            if (std::isfinite(a.damping)) cp.damping = a.damping;
            haptics::validateCouplingParams(cp);
            const double period = 1e-3;
            const double kMaxAsked = cp.maxStiffness;
            cp = haptics::clampToDevice(cp, *spec, period);

            haptics::SceneOptions so;
            so.surfaceIso = a.surfaceIso;
            if (cp.source == haptics::RaySource::Mesh) so.hardIso = cp.firstHit.threshold;
            if (a.deformable) so.surfaceIso = std::numeric_limits<double>::quiet_NaN();
            auto scene = haptics::Scene::fromVolume(vol, so);

            // The path: lateral box of the volume, surface on the face against the press.
            const Eigen::Vector3d press = parseAxis(a.pressAxis, "--press-axis");
            const int pa = axisIndex(press);
            const openvdb::BBoxd box = vol.worldBounds();
            if (box.empty()) {
                throw ValueError(label + ": expected a volume with active voxels, found none");
            }
            std::shared_ptr<const haptics::DeformableModel> body;
            if (a.deformable) {
                requirePositive(a.femCellMm, "--fem-cell-mm", "mm");
                requirePositive(a.youngKpa, "--young-kpa", "kPa");
                fem::VoxelizeOptions vo;
                vo.elementSize = a.femCellMm * 1e-3;
                vo.tissueThreshold = a.tissueHu;
                vo.boneThreshold = a.boneHu;
                fem::ElasticMaterial mat;
                mat.youngsModulus = a.youngKpa * 1e3;
                mat.poissonRatio = a.poisson;
                mat.dampingAlpha = a.femAlpha;
                mat.dampingBeta = a.femBeta;
                haptics::DeformableOptions dopt;
                dopt.filterWidth = a.filterMm * 1e-3;
                if (a.femSolver == "regions") {
                    dopt.solverKind = haptics::DeformableSolver::asyncRegions;
                    dopt.regions.tickSeconds = period;
                    dopt.regions.primaryNodes = a.primaryNodes;
                    dopt.regions.secondaryRate = a.secondaryHz;
                    dopt.regions.lod = a.lod;
                    // Offline runs are deterministic (secondary inline every period); a live
                    // session solves it on its own thread.
                    dopt.regions.threaded = a.realtime;
                }
                // Supported on the face opposite the pressed one.
                const auto support = static_cast<fem::BoxFace>(2 * pa + (press[pa] > 0 ? 1 : 0));
                body = haptics::DeformableModel::fromVolume(vol, vo, mat, support, dopt);
                scene->setDeformable(body);
            }
            const double half = 0.5 * vol.voxelSize();
            Eigen::Vector3d lo(box.min().x() - half, box.min().y() - half, box.min().z() - half);
            Eigen::Vector3d hi(box.max().x() + half, box.max().y() + half, box.max().z() + half);
            Eigen::Vector3d centre = 0.5 * (lo + hi);
            centre[pa] = press[pa] > 0 ? lo[pa] : hi[pa];
            if (!a.centreMm.empty()) {
                centre = 1e-3 * Eigen::Vector3d(a.centreMm[0], a.centreMm[1], a.centreMm[2]);
            }
            const int ua = (pa + 1) % 3, va = (pa + 2) % 3;
            Eigen::Vector3d u = Eigen::Vector3d::Unit(std::min(ua, va));
            Eigen::Vector3d v = Eigen::Vector3d::Unit(std::max(ua, va));
            if (!a.sweepAxis.empty()) {
                u = parseAxis(a.sweepAxis, "--sweep-axis");
                if (axisIndex(u) == pa)
                    throw ValueError("--sweep-axis: expected an axis across --press-axis " +
                                     a.pressAxis + ", found '" + a.sweepAxis + "'");
                v = Eigen::Vector3d::Unit(3 - pa - axisIndex(u));
            }
            double extentU = (hi - lo).dot(u.cwiseAbs()) - 10e-3;
            double extentV = (hi - lo).dot(v.cwiseAbs()) - 10e-3;
            if (!a.extentMm.empty()) {
                extentU = a.extentMm[0] * 1e-3;
                extentV = (a.extentMm.size() > 1 ? a.extentMm[1] : a.extentMm[0]) * 1e-3;
            }
            requirePositive(extentU * 1e3, "--extent (U)", "mm");
            requirePositive(extentV * 1e3, "--extent (V)", "mm");
            const double depth = a.depthMm * 1e-3;
            haptics::Trajectory traj;
            double duration = 0;
            const std::string& tk = a.trajectory;
            double speed = a.speedMmps;
            if (!std::isfinite(speed)) speed = tk == "sweep" ? 50 : 100;
            requirePositive(speed, "--speed", "mm/s");
            if (tk == "raster") {
                haptics::RasterTrajectory r;
                r.centre = centre;
                r.u = u;
                r.v = v;
                r.pressDirection = press;
                r.extentU = extentU;
                r.extentV = extentV;
                r.lineSpacingM = a.spacingMm * 1e-3;
                r.speedMps = speed * 1e-3;
                r.depthM = depth;
                traj = r;
                duration = haptics::trajectoryDuration(traj) + 0.2;
            } else if (tk == "sweep") {
                haptics::SweepTrajectory s;
                s.centre = centre;
                s.direction = u;
                s.pressDirection = press;
                s.lengthM = extentU;
                s.speedMps = speed * 1e-3;
                s.depthM = depth;
                traj = s;
                duration = haptics::trajectoryDuration(traj, a.passes);
            } else if (tk == "circle") {
                requirePositive(a.radiusMm, "--radius", "mm");
                requirePositive(a.frequencyHz, "--frequency", "Hz");
                haptics::CircleTrajectory c;
                c.centre = centre;
                c.u = u;
                c.v = v;
                c.pressDirection = press;
                c.radiusM = a.radiusMm * 1e-3;
                c.frequencyHz = a.frequencyHz;
                c.depthM = depth;
                traj = c;
                duration = haptics::trajectoryDuration(traj, a.passes);
            } else {
                haptics::PressTrajectory p;
                p.direction = press;
                p.start = centre - 5e-3 * press;  // start 5 mm outside the surface
                p.depthM = depth + 5e-3;
                p.pressSeconds = (depth + 5e-3) / (speed * 1e-3);
                p.holdSeconds = a.holdSeconds;
                traj = p;
                duration = haptics::trajectoryDuration(traj);
            }
            if (a.seconds > 0) duration = a.seconds;
            const auto ticks = static_cast<std::uint64_t>(std::ceil(duration / period));

            haptics::SessionParams sp;
            sp.coupling = cp;
            sp.proxy.staticFriction = a.muStatic;
            sp.proxy.dynamicFriction = a.muDynamic;
            sp.passivityControl = a.passivityControl;
            sp.servo.periodSeconds = period;
            // Real time: every tick's snapshot is queued in the trace ring and drained below
            // (16 Ki snapshots: seconds of slack at servo rates before any is dropped).
            if (a.realtime) sp.traceCapacity = 1u << 14;
            haptics::validateSessionParams(sp);
            haptics::SimulatedDevice device(*spec, traj, haptics::HandModel{}, period);
            haptics::Session session(scene, device, sp);

            // Run.
            std::vector<haptics::Snapshot> snaps;
            double wallSeconds = 0;
            std::string loopText;
            json loopJson;
            std::uint64_t traceDropped = 0;  // real time: ticks the trace ring could not hold
            const auto t0 = std::chrono::steady_clock::now();
            if (!a.realtime) {
                snaps = haptics::runOffline(session, ticks);
                wallSeconds =
                    std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
            } else {
                snaps.reserve(static_cast<std::size_t>(ticks) + 16);
                session.start();
                // Drain the per-tick trace ring (one row per tick, in order) until the servo
                // has run the asked-for ticks, then once more after stop() for the last ones.
                haptics::Snapshot s;
                const auto drain = [&] {
                    while (session.popTrace(s)) snaps.push_back(s);
                };
                while (session.latest().tick + 1 < ticks) {
                    drain();
                    std::this_thread::sleep_for(std::chrono::milliseconds(1));
                }
                session.stop();
                drain();
                traceDropped = session.traceDropped();
                if (traceDropped > 0)
                    std::fprintf(stderr,
                                 "palp: warning: the trace ring dropped %llu snapshots (the "
                                 "reader fell behind); the trace, map and summary miss those "
                                 "ticks\n",
                                 static_cast<unsigned long long>(traceDropped));
                wallSeconds =
                    std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
                const haptics::ServoStats st = session.stats();
                const haptics::RealtimeStatus& rs = session.realtime();
                char b[512];
                std::snprintf(b, sizeof b,
                              "servo: %llu ticks, %llu missed, %llu skipped; wake latency "
                              "p50 %.1f us p99 %.1f us max %.1f us; tick compute p50 %.1f us "
                              "p99 %.1f us max %.1f us\nreal-time: %s",
                              static_cast<unsigned long long>(st.ticks),
                              static_cast<unsigned long long>(st.misses),
                              static_cast<unsigned long long>(st.skipped), st.wakeLatency.p50 * 1e6,
                              st.wakeLatency.p99 * 1e6, st.wakeLatency.max * 1e6,
                              st.compute.p50 * 1e6, st.compute.p99 * 1e6, st.compute.max * 1e6,
                              rs.message.c_str());
                loopText = b;
                loopJson = {{"ticks", st.ticks},
                            {"misses", st.misses},
                            {"skipped", st.skipped},
                            {"wake_latency_us",
                             {{"p50", st.wakeLatency.p50 * 1e6},
                              {"p99", st.wakeLatency.p99 * 1e6},
                              {"max", st.wakeLatency.max * 1e6}}},
                            {"compute_us",
                             {{"p50", st.compute.p50 * 1e6},
                              {"p99", st.compute.p99 * 1e6},
                              {"max", st.compute.max * 1e6}}},
                            {"realtime", rs.message},
                            {"trace_dropped", traceDropped}};
            }
            const haptics::RunSummary sum = haptics::summarize(snaps);

            // Outputs.
            if (!a.trace.empty()) haptics::writeTraceCsv(a.trace, snaps);
            double mapLo = NAN, mapHi = NAN;
            if (!a.map.empty()) {
                haptics::MapPlane plane;
                plane.centre = centre;
                plane.u = u;
                plane.v = v;
                plane.extentU = extentU;
                plane.extentV = extentV;
                plane.pixelM = (a.mapPixelMm > 0 ? a.mapPixelMm : a.spacingMm) * 1e-3;
                haptics::ScalarMap m =
                    haptics::binSnapshots(snaps, plane, haptics::parseMapQuantity(a.mapQuantity),
                                          true, haptics::parseMapAnchor(a.mapAt));
                m.fillGaps(2);
                m.range(mapLo, mapHi);
                haptics::PngOptions po;
                po.colorMap = a.grey ? haptics::ColorMap::Grey : haptics::ColorMap::Heat;
                po.scale = std::clamp(static_cast<int>(256 / std::max(m.cols(), m.rows())), 1, 16);
                haptics::writeMapPng(a.map, m, po);
            }

            const double tps =
                wallSeconds > 0 ? static_cast<double>(snaps.size()) / wallSeconds : 0;
            if (a.json) {
                json j;
                j["input"] = label;
                j["device"] = std::string(spec->name);
                j["mode"] = haptics::couplingModeName(cp.mode);
                j["source"] = haptics::raySourceName(cp.source);
                j["trajectory"] = tk;
                j["k_base_npm"] = cp.baseStiffness;
                j["k_max_npm"] = cp.maxStiffness;
                j["k_max_asked_npm"] = kMaxAsked;
                j["l_max_mm"] = cp.bundle.length * 1e3;
                j["l_ref_mm"] = cp.referenceLength * 1e3;
                j["realtime"] = a.realtime;
                j["ticks"] = sum.ticks;
                j["simulated_seconds"] = sum.seconds;
                j["wall_seconds"] = wallSeconds;
                if (!a.realtime) j["ticks_per_second"] = tps;
                if (a.realtime) j["servo"] = loopJson;
                j["rays_per_frame_mean"] = sum.meanRays;
                j["rays_per_frame_max"] = sum.maxRays;
                j["max_force_n"] = sum.maxForceN;
                j["observer_energy_final_j"] = sum.finalObserverEnergy;
                j["observer_energy_min_j"] = sum.minObserverEnergy;
                j["contact_fraction"] = sum.contactFraction;
                j["stiffness_min_npm"] = sum.minStiffness;
                j["stiffness_max_npm"] = sum.maxStiffness;
                j["faulted_ticks"] = sum.faultedTicks;
                j["clamped_ticks"] = sum.clampedTicks;
                if (body) {
                    double maxDisp = 0;
                    for (const auto& s : snaps) maxDisp = std::max(maxDisp, s.maxDisplacement);
                    j["deformable"] = {{"nodes", body->model().mesh().nodeCount()},
                                       {"elements", body->model().mesh().elementCount()},
                                       {"surface_triangles", body->surface().triangles.size()},
                                       {"fixed_nodes", body->fixedNodes().size()},
                                       {"filter_mm", a.filterMm},
                                       {"cell_mm", a.femCellMm},
                                       {"young_kpa", a.youngKpa},
                                       {"solver", a.femSolver},
                                       {"max_displacement_mm", maxDisp * 1e3}};
                }
                if (!a.trace.empty()) j["trace"] = a.trace;
                if (!a.map.empty()) {
                    j["map"] = a.map;
                    j["map_quantity"] = a.mapQuantity;
                    j["map_at"] = a.mapAt;
                    j["map_range"] = {mapLo, mapHi};
                    j["map_right"] = axisName(u);
                    j["map_up"] = axisName(v);
                }
                std::printf("%s\n", j.dump(2).c_str());
            } else if (!globals().quiet) {
                std::printf(
                    "palp palpate: %s, %s/%s, %s on %s, k_s %.0f N/m, k_max %.0f "
                    "N/m, L_max %.0f mm, L_ref %.0f mm\n",
                    label.c_str(), haptics::couplingModeName(cp.mode),
                    haptics::raySourceName(cp.source), tk.c_str(), std::string(spec->name).c_str(),
                    cp.baseStiffness, cp.maxStiffness, cp.bundle.length * 1e3,
                    cp.referenceLength * 1e3);
                if (a.realtime) {
                    std::printf("%s\n", loopText.c_str());
                    std::printf("trace: %zu snapshots, %llu dropped\n", snaps.size(),
                                static_cast<unsigned long long>(traceDropped));
                } else {
                    std::printf(
                        "fast: %llu ticks (%.2f s simulated) in %.3f s wall: %.0f "
                        "ticks/s\n",
                        static_cast<unsigned long long>(sum.ticks), sum.seconds, wallSeconds, tps);
                }
                std::printf(
                    "rays per frame: mean %.1f, max %d; in contact %.0f %% of ticks; "
                    "stiffness %.0f-%.0f N/m\n",
                    sum.meanRays, sum.maxRays, 100 * sum.contactFraction, sum.minStiffness,
                    sum.maxStiffness);
                std::printf(
                    "max force %.3f N (%llu ticks clamped, %llu faulted); passivity "
                    "observer W: final %.3g J, min %.3g J\n",
                    sum.maxForceN, static_cast<unsigned long long>(sum.clampedTicks),
                    static_cast<unsigned long long>(sum.faultedTicks), sum.finalObserverEnergy,
                    sum.minObserverEnergy);
                if (body) {
                    double maxDisp = 0;
                    for (const auto& s : snaps) maxDisp = std::max(maxDisp, s.maxDisplacement);
                    std::printf(
                        "deformable: %d nodes, %d elements, %zu surface triangles, %zu fixed "
                        "nodes (support + bone), filter %.1f mm, E %.1f kPa, %s solver; largest "
                        "surface displacement %.2f mm\n",
                        body->model().mesh().nodeCount(), body->model().mesh().elementCount(),
                        body->surface().triangles.size(), body->fixedNodes().size(), a.filterMm,
                        a.youngKpa, a.femSolver.c_str(), maxDisp * 1e3);
                }
                if (!a.trace.empty()) std::printf("wrote %s\n", a.trace.c_str());
                if (!a.map.empty())
                    std::printf("wrote %s: %s from %.3g to %.3g; image right = %s, up = %s\n",
                                a.map.c_str(), a.mapQuantity.c_str(), mapLo, mapHi,
                                axisName(u).c_str(), axisName(v).c_str());
            }
            return 0;
        }};
}

}  // namespace palp::tool
