// The whole loop's energy (docs/algorithms.md sections 3 and 4): a Session with a simulated hand
// circling closed paths over the edges of the thesis phantoms, the proxy sliding under the probe,
// friction off and on. AVCEC must not give the hand energy where AVC does; the energy budget
// must close against the simulated device's own bookkeeping; the passivity controller must keep
// the observer non-negative with a finite force within the device's limit.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <map>
#include <memory>
#include <string>
#include <vector>

#include "palp/base/error.h"
#include "palp/haptics/devices/simulated_device.h"
#include "palp/haptics/devices/trajectory.h"
#include "palp/haptics/rendering/coupling_defaults.h"
#include "palp/haptics/session.h"
#include "palp/studies/energy_budget.h"
#include "palp/studies/offline_run.h"
#include "palp/volume/phantom.h"

namespace palp::haptics {
namespace {

namespace geo = volume::phantom_geometry;

constexpr double kPeriod = 1e-3;
constexpr int kLoops = 6;

const DeviceSpec& touch() {
    const DeviceSpec* s = findDeviceSpec("3D Systems Touch");
    if (!s) throw ValueError("no 3D Systems Touch spec");
    return *s;
}

std::shared_ptr<const Scene> phantomScene(const volume::PhantomParams& params) {
    static std::map<std::string, std::shared_ptr<const Scene>> cache;
    const std::string key = volume::Phantom(params).description();
    if (auto it = cache.find(key); it != cache.end()) return it->second;
    volume::PhantomSpec spec;
    spec.params = params;
    spec.voxelSize = 1e-3;
    const volume::Volume vol = volume::makePhantomVolume(spec);
    std::shared_ptr<Scene> scene = Scene::fromVolume(vol);
    scene->commit();
    cache.emplace(key, scene);
    return scene;
}

/// Where the plate's outline crosses the ray from the origin along (cos a, 0, sin a), m: the
/// edge the path circles (found on the phantom's exact geometry).
Eigen::Vector3d edgePoint(const volume::PhantomParams& params, double angle) {
    const volume::Phantom phantom(params);
    const bool avc = params.scene == volume::PhantomScene::Avc;
    const double depth = avc ? 0.5 * (geo::kAvcPlateTop + geo::kAvcPlateBottom)
                             : 0.5 * (geo::kAvcecPlateTop + geo::kAvcecPlateBottom);
    const double mid = 0.5 * (params.materials.softHu + params.materials.rigidHu);
    const Eigen::Vector3d dir(std::cos(angle), 0, std::sin(angle));
    double inside = 0, outside = 0.045;
    for (int i = 0; i < 40; ++i) {
        const double r = 0.5 * (inside + outside);
        (phantom.valueAt(r * dir + Eigen::Vector3d(0, depth, 0)) > mid ? inside : outside) = r;
    }
    return inside * dir;
}

struct Case {
    std::string name;
    volume::PhantomParams params;
    Eigen::Vector3d centre;
    RaySource source;
};

std::vector<Case> edgeCases() {
    std::vector<Case> cases;
    for (volume::PlateShape shape :
         {volume::PlateShape::Circle, volume::PlateShape::Triangle, volume::PlateShape::Rectangle,
          volume::PlateShape::Hexagon, volume::PlateShape::Pentagon}) {
        volume::PhantomParams p;
        p.scene = volume::PhantomScene::Avcec;
        p.shape = shape;
        // The edge at +x, and for the triangle also its vertex at +z (the worst case).
        cases.push_back({std::string("avcec ") + volume::shapeName(shape) + " +x edge", p,
                         edgePoint(p, 0), RaySource::VolumeFirstHit});
        if (shape == volume::PlateShape::Triangle) {
            cases.push_back(
                {"avcec triangle vertex", p, edgePoint(p, 0.5 * M_PI), RaySource::VolumeFirstHit});
            // Accumulate rays stop in the plate too (the scene's tau_stop): its worst corner.
            cases.push_back({"avcec triangle vertex, accumulate", p, edgePoint(p, 0.5 * M_PI),
                             RaySource::VolumeAccumulate});
        }
        if (shape == volume::PlateShape::Circle)
            cases.push_back({"avcec circle +x edge, accumulate", p, edgePoint(p, 0),
                             RaySource::VolumeAccumulate});
    }
    volume::PhantomParams avc;
    avc.scene = volume::PhantomScene::Avc;
    avc.quadrant = 0;  // box at x, z < 0
    cases.push_back(
        {"avc plate edge, first-hit", avc, edgePoint(avc, 0), RaySource::VolumeFirstHit});
    const double boxEdge = -geo::kAvcBoxOffset + geo::kAvcBoxHalfWidth;
    cases.push_back({"avc box edge, accumulate", avc,
                     Eigen::Vector3d(boxEdge, 0, -geo::kAvcBoxOffset),
                     RaySource::VolumeAccumulate});
    return cases;
}

struct LoopResult {
    EnergyBudget budget;
    double deviceWork = 0;  ///< the simulated device's own count over the same ticks, J
    double minObserver = 0, maxForce = 0;
    bool finite = true;
};

LoopResult runLoop(const Case& c, CouplingMode mode, double mu, bool controller,
                   double kMax = 2400) {
    SessionParams sp;
    sp.coupling = sceneCouplingDefaults(c.params.scene);
    sp.coupling.mode = mode;
    sp.coupling.source = c.source;
    sp.coupling.maxStiffness = kMax;
    limitStiffnessToDevice(sp.coupling, touch(), kPeriod);
    sp.proxy.staticFriction = mu;
    sp.proxy.dynamicFriction = 0.6 * mu;
    sp.passivityControl = controller;
    sp.servo.periodSeconds = kPeriod;
    CircleTrajectory path;
    path.centre = c.centre;
    path.radiusM = 0.003;
    path.frequencyHz = 1;
    path.depthM = 0.004;
    SimulatedDevice device(touch(), path, HandModel{}, kPeriod);
    Session session(phantomScene(c.params), device, sp);
    const double start = path.approachSeconds + path.rampSeconds;
    const auto ticks = static_cast<std::uint64_t>(std::ceil((start + kLoops) / kPeriod));
    LoopResult r;
    std::vector<Snapshot> snaps;
    snaps.reserve(ticks);
    double workAtStart = 0;
    for (std::uint64_t i = 0; i < ticks; ++i) {
        snaps.push_back(session.step());
        const Snapshot& s = snaps.back();
        // The device's count up to the step into this tick's probe position: the snapshot at
        // `start` is the budget's first.
        if (s.timeSeconds < start) workAtStart = device.workOnHand();
        r.minObserver = std::min(r.minObserver, s.observerEnergy);
        r.maxForce = std::max(r.maxForce, s.force.norm());
        r.finite = r.finite && s.force.allFinite();
    }
    r.budget = energyBudget(snaps, start);
    // The device applies tick n's force during the step to tick n+1's position; its last step
    // (into the tick after the last) is not in the snapshots.
    r.deviceWork = device.workOnHand() - workAtStart;
    return r;
}

TEST(EnergyLoop, BudgetClosesAgainstTheDevicesOwnCount) {
    // The budget's hand work (sent force times the probe's steps, from snapshots) is what the
    // simulated hand received (its own integration), and its terms add up.
    const Case c = edgeCases().front();
    for (CouplingMode mode : {CouplingMode::VC, CouplingMode::AVC, CouplingMode::AVCEC}) {
        const LoopResult r = runLoop(c, mode, 0.0, false);
        const EnergyBudget& b = r.budget;
        const double scale = std::max(1e-6, b.probePath * 1.0);  // ~1 N over the path
        EXPECT_NEAR(b.handWork, r.deviceWork, 1e-9 * scale + 0.02 * std::abs(r.deviceWork))
            << couplingModeName(mode);
        EXPECT_NEAR(b.handWork, b.created - b.storedChange - b.proxyWork + b.rendering, 1e-12)
            << couplingModeName(mode);
        EXPECT_GT(b.intervals, 5000u);
        if (mode == CouplingMode::VC) {
            // A constant-k spring with a frictionless proxy stores what it is given.
            EXPECT_LT(std::abs(b.created), 1e-3 * b.probePath);
        }
    }
}

TEST(EnergyLoop, AvcecGivesTheHandNoEnergyWhereAvcDoes) {
    std::printf("%-30s %-4s %12s %12s %12s %12s\n", "closed path (6 loops)", "mu", "AVC hand mJ",
                "AVCEC hand", "AVCEC proxy", "AVCEC W min");
    for (const Case& c : edgeCases()) {
        for (double mu : {0.0, 0.5}) {
            const LoopResult avc = runLoop(c, CouplingMode::AVC, mu, false);
            const LoopResult ec = runLoop(c, CouplingMode::AVCEC, mu, false);
            std::printf("%-30s %-4.1f %12.3f %12.3f %12.3f %12.3f\n", c.name.c_str(), mu,
                        avc.budget.handWork * 1e3, ec.budget.handWork * 1e3,
                        ec.budget.proxyWork * 1e3, ec.minObserver * 1e3);
            const double allowed = std::max(0.05 * avc.budget.handWork, 0.2e-3);
            EXPECT_LE(ec.budget.handWork, allowed) << c.name << " mu " << mu;
            if (mu > 0) {
                EXPECT_LE(ec.budget.handWork, 0.0) << c.name << " with friction";
            }
            EXPECT_TRUE(ec.finite);
            EXPECT_LE(ec.maxForce, touch().maxForceN + 1e-9);
        }
    }
}

TEST(EnergyLoop, ControllerKeepsTheObserverNonNegativeAtTheDevicesMaximumStiffness) {
    for (const Case& c : edgeCases()) {
        for (CouplingMode mode : {CouplingMode::AVC, CouplingMode::AVCEC}) {
            for (double mu : {0.0, 0.5}) {
                // k_max far above the Touch's: limitStiffnessToDevice brings it to the limit.
                const LoopResult r = runLoop(c, mode, mu, true, 1e5);
                EXPECT_GE(r.minObserver, -1e-12) << c.name << " " << couplingModeName(mode);
                EXPECT_TRUE(r.finite);
                EXPECT_LE(r.maxForce, touch().maxForceN + 1e-9);
            }
        }
    }
}

}  // namespace
}  // namespace palp::haptics
