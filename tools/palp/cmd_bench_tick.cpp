// palp bench tick: the full haptic tick (device read, proxy, ray bundle, force, safety, snapshot)
// of a real Session on a simulated hand pressed along a raster over a scan or the phantom, for
// VC, AVC and AVCEC with each ray source, the modes interleaved tick by tick so that VC is a
// baseline measured in the same run; the coupling alone is timed again on the recorded
// proxy/probe pairs.
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <memory>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "commands.h"
#include "option_checks.h"
#include "palp/base/error.h"
#include "palp/bench/ray_bench.h"
#include "palp/haptics/devices/simulated_device.h"
#include "palp/haptics/devices/trajectory.h"
#include "palp/haptics/rendering/coupling.h"
#include "palp/haptics/rendering/coupling_defaults.h"
#include "palp/haptics/session.h"
#include "palp/kernels/volume_ray.h"
#include "palp/volume/load.h"
#include "palp/volume/phantom.h"

namespace palp::tool {

namespace fs = std::filesystem;
using nlohmann::json;
using Clock = std::chrono::steady_clock;

namespace {

constexpr double kPeriod = 1e-3;

struct Variant {
    haptics::CouplingMode mode;
    haptics::RaySource source;
    int ring;
};

// VC first: the baseline of every other line.
constexpr Variant kVariants[] = {
    {haptics::CouplingMode::VC, haptics::RaySource::VolumeFirstHit, 0},
    {haptics::CouplingMode::AVC, haptics::RaySource::VolumeFirstHit, 0},
    {haptics::CouplingMode::AVC, haptics::RaySource::VolumeAccumulate, 0},
    {haptics::CouplingMode::AVC, haptics::RaySource::Mesh, 0},
    {haptics::CouplingMode::AVC, haptics::RaySource::VolumeFirstHit, 8},
    {haptics::CouplingMode::AVCEC, haptics::RaySource::VolumeFirstHit, 0},
    {haptics::CouplingMode::AVCEC, haptics::RaySource::VolumeAccumulate, 0},
    {haptics::CouplingMode::AVCEC, haptics::RaySource::Mesh, 0},
    {haptics::CouplingMode::AVCEC, haptics::RaySource::VolumeFirstHit, 8},
};

const char* modeText(haptics::CouplingMode m) {
    switch (m) {
        case haptics::CouplingMode::VC:
            return "VC";
        case haptics::CouplingMode::AVC:
            return "AVC";
        case haptics::CouplingMode::AVCEC:
            return "AVCEC";
    }
    return "?";
}

// Rays a tick of @p v casts (Coupling's documentation: AVC traces centre + ring, AVCEC all).
int nominalRays(const Variant& v) {
    if (v.mode == haptics::CouplingMode::VC) return 0;
    return v.mode == haptics::CouplingMode::AVC ? 1 + v.ring : 17 + v.ring;
}

std::string variantName(const Variant& v) {
    if (v.mode == haptics::CouplingMode::VC) return "VC";
    const int r = nominalRays(v);
    std::string s = std::string(modeText(v.mode)) + " (" + std::to_string(r) +
                    (r == 1 ? " ray, " : " rays, ") + haptics::raySourceName(v.source);
    if (v.ring > 0) s += ", ring " + std::to_string(v.ring);
    return s + ")";
}

double percentile(std::vector<double> v, double q) {
    if (v.empty()) return 0;
    const auto n = v.size();
    auto k = static_cast<std::size_t>(std::ceil(q * static_cast<double>(n)));
    k = std::clamp<std::size_t>(k, 1, n) - 1;
    std::nth_element(v.begin(), v.begin() + static_cast<std::ptrdiff_t>(k), v.end());
    return v[k];
}

struct Stats {
    double p50 = 0, p99 = 0, max = 0, mean = 0;
    std::size_t n = 0;
};

Stats stats(const std::vector<double>& us) {
    Stats s;
    s.n = us.size();
    if (us.empty()) return s;
    s.p50 = percentile(us, 0.50);
    s.p99 = percentile(us, 0.99);
    s.max = *std::max_element(us.begin(), us.end());
    double sum = 0;
    for (double x : us) sum += x;
    s.mean = sum / static_cast<double>(us.size());
    return s;
}

json statsJson(const Stats& s) {
    return {{"p50_us", s.p50},
            {"p99_us", s.p99},
            {"max_us", s.max},
            {"mean_us", s.mean},
            {"ticks", s.n}};
}

/// The pressed raster, chosen from where the surface is. The surface iso is traced along the
/// press axis from the volume box's face on a 2 mm grid over the lateral box; the raster plane
/// sits at the 25th percentile of the skin depth (the outer quarter of the surface), covering
/// the bounding rectangle of the grid points whose skin lies within 10 mm of that plane (less
/// 2 mm per side, and less half a line spacing per side along u, where the turns bulge out),
/// and the target is pressed 4 mm plus the median excess depth of those points below the
/// plane. On a flat phantom this is the lateral box less 2 mm, pressed 4 mm.
struct PathChoice {
    haptics::RasterTrajectory raster;
    double faceToPlaneM = 0;  ///< from the box face to the raster plane, m
    double hitFraction = 0;   ///< grid points whose ray found the surface
    int gridPoints = 0;
};

PathChoice choosePath(const volume::Volume& vol, const haptics::Scene& scene, double iso,
                      const Eigen::Vector3d& press, std::uint64_t ticks) {
    const openvdb::BBoxd box = vol.worldBounds();
    if (box.empty())
        throw ValueError("bench tick: expected a volume with active voxels, found none");
    const double half = 0.5 * vol.voxelSize();
    const Eigen::Vector3d lo(box.min().x() - half, box.min().y() - half, box.min().z() - half);
    const Eigen::Vector3d hi(box.max().x() + half, box.max().y() + half, box.max().z() + half);
    const int pa = axisIndex(press);
    const int ua = (pa + 1) % 3 < (pa + 2) % 3 ? (pa + 1) % 3 : (pa + 2) % 3;
    const int va = 3 - pa - ua;
    const Eigen::Vector3d u = Eigen::Vector3d::Unit(ua), v = Eigen::Vector3d::Unit(va);
    const double face = press[pa] > 0 ? lo[pa] : hi[pa];
    const double depthRange = hi[pa] - lo[pa];

    const kernels::VolumeView* view = scene.volumeView();
    kernels::FirstHitParams fh;
    fh.threshold = static_cast<float>(iso);
    fh.step = std::max(0.25e-3, 0.5 * vol.voxelSize());
    struct Hit {
        double u, v, t;
    };
    std::vector<Hit> hits;
    PathChoice pc;
    const double grid = 2e-3;
    for (double a = lo[ua] + 1e-3; a < hi[ua]; a += grid) {
        for (double b = lo[va] + 1e-3; b < hi[va]; b += grid) {
            ++pc.gridPoints;
            Eigen::Vector3d o = Eigen::Vector3d::Zero();
            o[pa] = face - 1e-3 * press[pa];
            o[ua] = a;
            o[va] = b;
            const kernels::RayHit h = kernels::firstHit(*view, o, press, depthRange + 2e-3, fh);
            if (h.hit) hits.push_back({a, b, static_cast<double>(h.t) - 1e-3});
        }
    }
    if (hits.empty()) {
        throw ValueError("bench tick: expected the surface iso " + std::to_string(iso) +
                         " to be crossed along the press axis inside the volume box, found no "
                         "crossing (try --surface-iso or --press-axis)");
    }
    pc.hitFraction = static_cast<double>(hits.size()) / pc.gridPoints;
    std::vector<double> ts;
    for (const Hit& h : hits) ts.push_back(h.t);
    const double t25 = percentile(ts, 0.25);
    double u0 = 1e9, u1 = -1e9, v0 = 1e9, v1 = -1e9;
    std::vector<double> excess;
    for (const Hit& h : hits) {
        if (h.t > t25 + 10e-3) continue;
        u0 = std::min(u0, h.u);
        u1 = std::max(u1, h.u);
        v0 = std::min(v0, h.v);
        v1 = std::max(v1, h.v);
        excess.push_back(std::max(0.0, h.t - t25));
    }
    const double extentU = std::max(2e-3, u1 - u0 - 4e-3);
    const double extentV = std::max(2e-3, v1 - v0 - 4e-3);

    haptics::RasterTrajectory& r = pc.raster;
    r.centre = Eigen::Vector3d::Zero();
    r.centre[pa] = face + t25 * press[pa];
    r.centre[ua] = 0.5 * (u0 + u1);
    r.centre[va] = 0.5 * (v0 + v1);
    r.u = u;
    r.v = v;
    r.pressDirection = press;
    r.extentU = extentU;
    r.extentV = extentV;
    r.depthM = 4e-3 + percentile(excess, 0.5);
    // Start outside the volume box (5 mm before its face), so the probe never starts inside.
    r.approachM = std::max(5e-3, t25 + 5e-3 - r.depthM);
    r.approachSeconds = std::max(0.3, (r.approachM + r.depthM) / 0.05);
    r.speedMps = 0.1;
    // Line spacing so that the raster fills the run (lines + half circles ~ path length).
    const double pathM =
        r.speedMps * std::max(0.5, static_cast<double>(ticks) * kPeriod - r.approachSeconds);
    r.lineSpacingM = std::clamp(extentU * extentV / std::max(pathM - extentU, 1e-3), 1e-3,
                                std::max(1e-3, extentV));
    // The half-circle turns bulge lineSpacing / 2 beyond the rectangle in u: keep them inside.
    r.extentU = std::max(2e-3, extentU - r.lineSpacingM);
    pc.faceToPlaneM = t25;
    return pc;
}

// A tangent frame perpendicular to @p d (the coupling orthonormalises it anyway).
void frameOf(const Eigen::Vector3d& d, Eigen::Vector3d& t1, Eigen::Vector3d& t2) {
    Eigen::Vector3d n = d.norm() > 0 ? Eigen::Vector3d(d.normalized()) : Eigen::Vector3d::UnitY();
    int i = 0;
    n.cwiseAbs().minCoeff(&i);
    t1 = (Eigen::Vector3d::Unit(i) - n[i] * n).normalized();
    t2 = n.cross(t1);
}

struct Run {
    Variant variant;
    haptics::CouplingParams params;
    std::unique_ptr<haptics::SimulatedDevice> device;
    std::unique_ptr<haptics::Session> session;
    std::vector<double> tickUs, contactTickUs, couplingUs;
    std::vector<Eigen::Vector3d> proxy, probe;
    std::uint64_t contactTicks = 0, rayTicks = 0, raysCast = 0, clamped = 0;
    double maxForce = 0;
};

/// The options of `palp bench tick`.
struct TickArgs {
    std::string volume;
    double voxelMm = 0;
    std::uint64_t ticks = 20000;
    double surfaceIso = -400;
    double threshold = 300;
    std::string pressAxis = "+y";
    std::string device = "3D Systems Touch";
    bool json = false;
    bool noPin = false;
};

/// One Run per variant, each a Session on its own simulated hand along @p path, buffers reserved
/// for @p a.ticks ticks.
std::vector<Run> makeRuns(const TickArgs& a, const haptics::DeviceSpec* spec,
                          const std::shared_ptr<haptics::Scene>& scene, const PathChoice& path) {
    haptics::CouplingParams base = haptics::scanCouplingDefaults();
    base.firstHit.threshold = static_cast<float>(a.threshold);
    base.accumulate.sigma =
        kernels::TransferFunction::step(static_cast<float>(a.threshold), 1000.0f);
    std::vector<Run> runs;
    for (const Variant& v : kVariants) {
        Run r;
        r.variant = v;
        r.params = base;
        r.params.mode = v.mode;
        r.params.source = v.source;
        r.params.bundle.ringCount = v.ring;
        haptics::validateCouplingParams(r.params);
        haptics::limitStiffnessToDevice(r.params, *spec, kPeriod);
        haptics::SessionParams sp;
        sp.coupling = r.params;
        sp.servo.periodSeconds = kPeriod;
        haptics::validateSessionParams(sp);
        r.device = std::make_unique<haptics::SimulatedDevice>(*spec, path.raster,
                                                              haptics::HandModel{}, kPeriod);
        r.session = std::make_unique<haptics::Session>(scene, *r.device, sp);
        const auto n = static_cast<std::size_t>(a.ticks);
        r.tickUs.reserve(n);
        r.contactTickUs.reserve(n);
        r.couplingUs.reserve(n);
        r.proxy.reserve(n);
        r.probe.reserve(n);
        runs.push_back(std::move(r));
    }
    return runs;
}

/// Full ticks of every run, interleaved; the starting mode rotates each tick.
void runTicks(std::vector<Run>& runs, std::uint64_t ticks) {
    const std::size_t nv = runs.size();
    for (std::uint64_t i = 0; i < ticks; ++i) {
        for (std::size_t j = 0; j < nv; ++j) {
            Run& r = runs[(j + i) % nv];
            const auto t0 = Clock::now();
            const haptics::Snapshot& s = r.session->step();
            const auto t1 = Clock::now();
            const double us = std::chrono::duration<double, std::micro>(t1 - t0).count();
            r.tickUs.push_back(us);
            const bool contact = s.contactCount > 0 || s.distance > 1e-6;
            if (contact) {
                ++r.contactTicks;
                r.contactTickUs.push_back(us);
            }
            if (s.rays > 0) {
                ++r.rayTicks;
                r.raysCast += static_cast<std::uint64_t>(s.rays);
            }
            if (s.clamped) ++r.clamped;
            r.maxForce = std::max(r.maxForce, s.force.norm());
            r.proxy.push_back(s.proxy);
            r.probe.push_back(s.probe);
        }
    }
}

/// The coupling alone on the recorded pairs (velocities by finite difference, a tangent frame
/// perpendicular to proxy -> probe), interleaved like the ticks; returns a sum that keeps
/// the work alive.
double replayCouplings(std::vector<Run>& runs, const haptics::Scene& scene, std::uint64_t ticks) {
    const std::size_t nv = runs.size();
    std::vector<haptics::Coupling> couplings;
    couplings.reserve(nv);
    for (const Run& r : runs)
        couplings.emplace_back(scene.volumeView(), &scene.hardMeshes(), r.params);
    haptics::CouplingOutput out;
    double sink = 0;
    for (std::uint64_t i = 1; i < ticks; ++i) {
        for (std::size_t j = 0; j < nv; ++j) {
            const std::size_t k = (j + i) % nv;
            Run& r = runs[k];
            const Eigen::Vector3d& py = r.proxy[i];
            const Eigen::Vector3d& pb = r.probe[i];
            const Eigen::Vector3d vpy = (py - r.proxy[i - 1]) / kPeriod;
            const Eigen::Vector3d vpb = (pb - r.probe[i - 1]) / kPeriod;
            Eigen::Vector3d t1, t2;
            frameOf(pb - py, t1, t2);
            const auto c0 = Clock::now();
            couplings[k].compute(py, pb, vpy, vpb, t1, t2, out);
            const auto c1 = Clock::now();
            r.couplingUs.push_back(std::chrono::duration<double, std::micro>(c1 - c0).count());
            sink += out.stiffness;
        }
    }
    return sink;
}

/// The figures of every run, as text or JSON (--json), VC the baseline of the others.
void printReport(const TickArgs& a, const std::vector<Run>& runs, const std::string& label,
                 const volume::Volume& vol, const haptics::DeviceSpec* spec, const PathChoice& path,
                 const Eigen::Vector3d& press, bool pinned) {
    double load[3] = {0, 0, 0};
    const int nLoad = getloadavg(load, 3);
    const std::string machine = kernels::machineDescription();
    const Stats vc = stats(runs[0].tickUs);
    const haptics::RasterTrajectory& rr = path.raster;
    const int pa = axisIndex(press);
    json j;
    if (a.json) {
        j["machine"] = machine;
        j["pinned"] = pinned;
        j["load_average"] = nLoad > 0 ? json{load[0], load[1], load[2]} : json();
        j["scene"] = label;
        j["voxel_mm"] = vol.voxelSize() * 1e3;
        j["device"] = std::string(spec->name);
        j["ticks"] = a.ticks;
        j["surface_iso"] = a.surfaceIso;
        j["threshold"] = a.threshold;
        j["raster"] = {
            {"press_axis", a.pressAxis},
            {"centre_mm", {rr.centre.x() * 1e3, rr.centre.y() * 1e3, rr.centre.z() * 1e3}},
            {"extent_mm", {rr.extentU * 1e3, rr.extentV * 1e3}},
            {"line_spacing_mm", rr.lineSpacingM * 1e3},
            {"depth_mm", rr.depthM * 1e3},
            {"speed_mmps", rr.speedMps * 1e3},
            {"face_to_plane_mm", path.faceToPlaneM * 1e3},
            {"surface_hit_fraction", path.hitFraction}};
        j["lines"] = json::array();
    } else {
        std::printf(
            "machine: %s; measuring thread %s; load average %.2f %.2f %.2f (shared "
            "machine)\n",
            machine.c_str(), pinned ? "pinned to one core" : "not pinned", load[0], load[1],
            load[2]);
        std::printf(
            "scene: %s, voxel %.2f mm, surface %g, hard %g, device %s; raster pressed "
            "%s at %.1f mm (%.1f mm in from the box face), %.0f x %.0f mm around "
            "(%.1f, %.1f, %.1f) mm, lines %.1f mm apart, depth %.1f mm, %.0f mm/s; "
            "%llu ticks per mode\n",
            label.c_str(), vol.voxelSize() * 1e3, a.surfaceIso, a.threshold,
            std::string(spec->name).c_str(), a.pressAxis.c_str(), rr.centre[pa] * 1e3,
            path.faceToPlaneM * 1e3, rr.extentU * 1e3, rr.extentV * 1e3, rr.centre.x() * 1e3,
            rr.centre.y() * 1e3, rr.centre.z() * 1e3, rr.lineSpacingM * 1e3, rr.depthM * 1e3,
            rr.speedMps * 1e3, static_cast<unsigned long long>(a.ticks));
    }
    for (const Run& r : runs) {
        const Stats t = stats(r.tickUs);
        const Stats tc = stats(r.contactTickUs);
        const Stats c = stats(r.couplingUs);
        const double contact = static_cast<double>(r.contactTicks) / static_cast<double>(a.ticks);
        const double meanRays =
            r.rayTicks ? static_cast<double>(r.raysCast) / static_cast<double>(r.rayTicks) : 0.0;
        const std::string name = variantName(r.variant);
        if (a.json) {
            j["lines"].push_back({{"name", name},
                                  {"mode", modeText(r.variant.mode)},
                                  {"source", haptics::raySourceName(r.variant.source)},
                                  {"ring", r.variant.ring},
                                  {"rays_nominal", nominalRays(r.variant)},
                                  {"rays_mean", meanRays},
                                  {"tick", statsJson(t)},
                                  {"tick_in_contact", statsJson(tc)},
                                  {"coupling", statsJson(c)},
                                  {"rest_p50_us", t.p50 - c.p50},
                                  {"ratio_p50_to_vc", t.p50 / vc.p50},
                                  {"ratio_p99_to_vc", t.p99 / vc.p99},
                                  {"budget_p99_percent", t.p99 / 10.0},
                                  {"contact_fraction", contact},
                                  {"max_force_n", r.maxForce},
                                  {"clamped_ticks", r.clamped}});
            continue;
        }
        if (r.variant.mode == haptics::CouplingMode::VC) {
            std::printf(
                "tick VC (baseline), %s: p50 %.1f us / p99 %.1f us / max %.0f us; 1 "
                "ms budget used at p99: %.1f %%\n",
                label.c_str(), t.p50, t.p99, t.max, t.p99 / 10.0);
        } else {
            std::printf(
                "tick %s, %s: p50 %.1f us / p99 %.1f us / max %.0f us; VC %.1f / "
                "%.1f / %.0f us; %.1fx / %.1fx; 1 ms budget used at p99: %.1f %%\n",
                name.c_str(), label.c_str(), t.p50, t.p99, t.max, vc.p50, vc.p99, vc.max,
                t.p50 / vc.p50, t.p99 / vc.p99, t.p99 / 10.0);
        }
        std::printf(
            "    in contact %.0f %% of ticks (contact ticks p50 %.1f / p99 %.1f us); "
            "coupling alone p50 %.1f / p99 %.1f / max %.0f us; tick - coupling at p50 "
            "(proxy, device, safety, snapshot) %.1f us; rays/tick %.1f; max force %.2f N\n",
            100 * contact, tc.p50, tc.p99, c.p50, c.p99, c.max, t.p50 - c.p50, meanRays,
            r.maxForce);
    }
    if (a.json) std::printf("%s\n", j.dump(2).c_str());
}

}  // namespace

Command addBenchTick(CLI::App& bench) {
    auto args = std::make_shared<TickArgs>();
    CLI::App* app = bench.add_subcommand(
        "tick",
        "Full haptic tick (proxy + bundle + force) of a Session for VC, AVC and AVCEC and each "
        "ray source, interleaved tick by tick, VC as the same-run baseline");
    app->add_option("--volume", args->volume,
                    "A .vdb (or any scan palp reads); default: the AVC phantom");
    app->add_option("--voxel", args->voxelMm,
                    "Voxel edge, mm: resample --volume (default: as stored) or the phantom's "
                    "(default 0.5)")
        ->check(within(bounds::kSpacing, kMm));
    app->add_option("--ticks", args->ticks, "Ticks per mode (default 20000: 20 s simulated)")
        ->check(integerIn(100, 10000000));
    app->add_option("--surface-iso", args->surfaceIso,
                    "Value of the surface the proxy slides on (default -400 HU: skin)")
        ->check(within(bounds::kVolumeValue));
    app->add_option("--threshold", args->threshold,
                    "Hard structures: first-hit threshold, accumulate step and mesh iso (default "
                    "300 HU: bone)")
        ->check(within(bounds::kVolumeValue));
    app->add_option("--press-axis", args->pressAxis,
                    "Press direction into the body (default +y: anterior to posterior)");
    app->add_option("--device", args->device, "Device class whose limits apply");
    app->add_flag("--json", args->json, "Print the figures as JSON");
    app->add_flag("--no-pin", args->noPin, "Do not pin the measuring thread to one core");

    return {app, [args]() -> int {
                const TickArgs& a = *args;
                const haptics::DeviceSpec* spec = haptics::findDeviceSpec(a.device);
                if (!spec) {
                    throw ValueError(
                        "--device: expected a device class of palp's table (e.g. "
                        "'3D Systems Touch'), found '" +
                        a.device + "'");
                }
                const Eigen::Vector3d press = parseAxis(a.pressAxis, "--press-axis");
                const bool quiet = globals().quiet || a.json;

                // Scene.
                volume::Volume vol;
                std::string label;
                if (!a.volume.empty()) {
                    volume::LoadOptions lo;
                    if (a.voxelMm > 0) lo.resample.voxelSize = a.voxelMm * 1e-3;
                    vol = volume::load({fs::path(a.volume)}, lo);
                    label = fs::path(a.volume).filename().string();
                } else {
                    volume::PhantomSpec ps;
                    ps.params.scene = volume::PhantomScene::Avc;
                    ps.params.quadrant = 2;
                    ps.voxelSize = (a.voxelMm > 0 ? a.voxelMm : 0.5) * 1e-3;
                    vol = volume::makePhantomVolume(ps);
                    label = "AVC phantom";
                }
                if (!quiet)
                    std::fprintf(stderr, "palp: building the scene of %s...\n", label.c_str());
                haptics::SceneOptions so;
                so.surfaceIso = a.surfaceIso;
                so.hardIso = a.threshold;
                const auto scene = haptics::Scene::fromVolume(vol, so);
                const PathChoice path = choosePath(vol, *scene, a.surfaceIso, press, a.ticks);

                std::vector<Run> runs = makeRuns(a, spec, scene, path);
                const bool pinned = !a.noPin && kernels::pinCurrentThread();
                if (!quiet) {
                    std::fprintf(stderr,
                                 "palp: %llu ticks x %zu modes, interleaved tick by tick...\n",
                                 static_cast<unsigned long long>(a.ticks), runs.size());
                }

                // Full ticks, interleaved; the starting mode rotates each tick.
                runTicks(runs, a.ticks);

                // The coupling alone on the recorded pairs, interleaved likewise.
                const double sink = replayCouplings(runs, *scene, a.ticks);

                printReport(a, runs, label, vol, spec, path, press, pinned);
                if (sink == 42.0) std::fprintf(stderr, " ");  // keep the replay alive
                return 0;
            }};
}

}  // namespace palp::tool
