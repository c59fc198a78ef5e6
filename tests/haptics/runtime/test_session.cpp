// Scene and Session: the per-tick pipeline's physics (VC press, workspace transform, first-hit
// fields per threshold), safety at every tick (start inside, D -> 0, NaN samples, empty scene),
// zero allocations per tick and cross-faded parameter changes. The passivity observer and
// controller and the device's stiffness limit are in test_session_passivity.cpp; real-time runs
// with a viewer and a producer thread in test_session_threads.cpp.
#include <gtest/gtest.h>
#include <tbb/task_arena.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <limits>
#include <string>
#include <vector>

#include "alloc_counter.h"
#include "palp/base/error.h"
#include "palp/haptics/session.h"
#include "session_fixtures.h"
#include "session_test_fixture.h"

namespace palp::haptics {
namespace {

using namespace sfix;  // SessionTest, kModes, expectSafe, at, kT, PathDevice, touchX

TEST_F(SessionTest, SceneFromVolumeHasSurfacesHardMeshesAndView) {
    EXPECT_NE(sScene->volumeView(), nullptr);
    EXPECT_GT(sScene->surfaces().triangleCount(), 1000u);
    EXPECT_GT(sScene->hardMeshes().triangleCount(), 100u);
    EXPECT_TRUE(sScene->surfaces().committed());

    tbb::task_arena single(1);  // as in SetUpTestSuite
    single.execute([] {
        SceneOptions above;
        above.surfaceIso = 5000;  // above every value: no surface
        EXPECT_THROW(Scene::fromVolume(*sVolume, above), ValueError);
        SceneOptions none;
        none.surfaceIso = std::numeric_limits<double>::quiet_NaN();
        const auto bare = Scene::fromVolume(*sVolume, none);
        EXPECT_TRUE(bare->surfaces().empty());
        EXPECT_TRUE(bare->hardMeshes().empty());
    });
}

TEST_F(SessionTest, RejectsBadParamsAndSourcesWithoutData) {
    PathDevice dev({{0, at(0, -0.01, 0)}});
    SessionParams p = params(CouplingMode::VC);
    p.workspace.scale = 0;
    EXPECT_THROW(Session(sScene, dev, p), ValueError);
    p = params(CouplingMode::VC);
    p.workspace.rotation(0, 0) = 2;
    EXPECT_THROW(Session(sScene, dev, p), ValueError);
    p = params(CouplingMode::VC);
    p.crossFadeSeconds = -1;
    EXPECT_THROW(Session(sScene, dev, p), ValueError);
    EXPECT_THROW(Session(nullptr, dev, params(CouplingMode::VC)), ValueError);

    auto empty = std::make_shared<Scene>();
    empty->commit();
    EXPECT_THROW(Session(empty, dev, params(CouplingMode::AVC)), ValueError);  // no volume
    EXPECT_THROW(Session(empty, dev, params(CouplingMode::AVC, RaySource::Mesh)), ValueError);
    Session vc(empty, dev, params(CouplingMode::VC));
    Command c;
    c.kind = Command::Kind::SetCoupling;
    c.coupling = params(CouplingMode::AVCEC).coupling;
    EXPECT_THROW(vc.send(c), ValueError);  // checked off the servo thread
    c.coupling.mode = CouplingMode::VC;
    c.coupling.baseStiffness = -1;
    EXPECT_THROW(vc.send(c), ValueError);
    c.kind = Command::Kind::SetProxy;
    c.proxy.staticFriction = 0.1;
    c.proxy.dynamicFriction = 0.2;  // mu_d > mu_s
    EXPECT_THROW(vc.send(c), ValueError);
}

// First-hit fields: one for the starting threshold, one more for each new threshold a coupling
// command brings (built in send(), off the servo thread), none again for a threshold used
// before. The same press then feels the same with the new threshold's field as a session that
// started with that threshold (to float rounding: both march with a field).
TEST_F(SessionTest, CouplingCommandsBringAFieldForANewThreshold) {
    const std::vector<PathDevice::Key> path = {{0, at(0.004, -0.004, 0.003)},
                                               {0.3, at(0.004, 0.002, 0.003)},
                                               {1.0, at(0.004, 0.002, 0.003)}};
    PathDevice dev(path), other(path);
    SessionParams p = params(CouplingMode::AVC);
    Session session(sScene, dev, p);
    EXPECT_EQ(session.hitFieldCount(), 1u);
    Command c;
    c.kind = Command::Kind::SetCoupling;
    c.coupling = p.coupling;
    c.coupling.firstHit.threshold = 200;
    ASSERT_TRUE(session.send(c));
    EXPECT_EQ(session.hitFieldCount(), 2u);
    c.coupling.firstHit.threshold = p.coupling.firstHit.threshold;
    ASSERT_TRUE(session.send(c));
    c.coupling.firstHit.threshold = 200;
    ASSERT_TRUE(session.send(c));
    EXPECT_EQ(session.hitFieldCount(), 2u);  // both thresholds seen before
    SessionParams q = p;
    q.coupling.firstHit.threshold = 200;
    Session reference(sScene, other, q);
    Snapshot a, b;
    for (int i = 0; i < 900; ++i) {
        a = session.step();
        b = reference.step();
    }
    EXPECT_GT(a.force.norm(), 0.1);  // pressed, after the cross-fades
    EXPECT_NEAR(a.rayLength, b.rayLength, 1e-5);
    EXPECT_NEAR(a.stiffness, b.stiffness, 1e-3 * b.stiffness);
    EXPECT_LE((a.force - b.force).norm(), 1e-3 * b.force.norm());
}

// VC press: the probe held 2 mm below the surface; F = k (x_py - x_pb) with the proxy on the
// surface, pointing out of it (-y), |F| = k D.
TEST_F(SessionTest, VcPressGivesSpringForceOutOfTheSurface) {
    PathDevice dev({{0, at(0.004, -0.004, 0.003)},
                    {0.3, at(0.004, 0.002, 0.003)},
                    {1.0, at(0.004, 0.002, 0.003)}});
    Session session(sScene, dev, params(CouplingMode::VC));
    Snapshot s;
    for (int i = 0; i < 600; ++i) s = session.step();
    EXPECT_TRUE(s.gateOpen);
    EXPECT_EQ(s.contactCount, 1);
    EXPECT_NEAR(s.proxy.y(), 0.0, 0.5e-3);  // on the skin iso-surface
    EXPECT_NEAR(s.proxy.x(), 0.004, 1e-6);  // no friction, normal press: straight above
    EXPECT_NEAR(s.proxy.z(), 0.003, 1e-6);
    const double depth = s.probe.y() - s.proxy.y();
    EXPECT_GT(depth, 1.4e-3);
    EXPECT_NEAR(s.distance, depth, 1e-9);
    EXPECT_NEAR(s.force.y(), -300 * depth, 1e-9);
    EXPECT_NEAR(s.force.x(), 0, 1e-6);
    EXPECT_NEAR(s.force.z(), 0, 1e-6);
    EXPECT_DOUBLE_EQ(s.stiffness, 300);
    EXPECT_NEAR(s.couplingEnergy, 0.5 * 300 * depth * depth, 1e-12);
    EXPECT_FALSE(s.clamped);
    // The device got the same force (identity workspace).
    EXPECT_TRUE(dev.force().isApprox(s.force, 1e-12));
}

// A rotated and scaled workspace: the probe is the mapped device position, and the force is
// rotated back into the device frame.
TEST_F(SessionTest, WorkspaceTransformMapsProbeAndForce) {
    // Device frame: z is "into the surface"; world: +y. Rotation about x by -90 degrees maps
    // device +z to world +y.
    SessionParams p = params(CouplingMode::VC);
    p.workspace.rotation = Eigen::AngleAxisd(-M_PI / 2, Eigen::Vector3d::UnitX()).matrix();
    p.workspace.scale = 2;
    p.workspace.offset = at(0.001, 0, 0);
    PathDevice dev({{0, at(0, 0, -0.002)}, {0.3, at(0, 0, 0.001)}, {1.0, at(0, 0, 0.001)}});
    Session session(sScene, dev, p);
    Snapshot s;
    for (int i = 0; i < 500; ++i) s = session.step();
    const Eigen::Vector3d expectedProbe =
        p.workspace.offset + 2 * (p.workspace.rotation * at(0, 0, 0.001));
    EXPECT_TRUE(s.probe.isApprox(expectedProbe, 1e-12));
    EXPECT_NEAR(s.probe.y(), 0.002, 1e-12);
    EXPECT_LT(s.force.y(), -0.3);  // out of the surface in the world
    const Eigen::Vector3d deviceForce = p.workspace.rotation.transpose() * s.force;
    EXPECT_TRUE(dev.force().isApprox(deviceForce, 1e-12));
    EXPECT_LT(dev.force().z(), -0.3);  // out of the surface in the device frame
}

// (a) The probe starts 5 mm inside the block, then withdraws and presses again: nothing is
// sent before the gate opens, the opening tick sends less than the threshold, the force then
// changes continuously (bounded step per tick), the proxy is not trapped inside the surface
// while the probe leaves, and the surface holds once the probe comes back.
TEST_F(SessionTest, StartInsideGeometryDoesNotKick) {
    for (CouplingMode mode : kModes) {
        PathDevice dev({{0, at(0.0, 0.005, 0.0)},
                        {0.1, at(0.0, 0.005, 0.0)},
                        {0.6, at(0.0, -0.005, 0.0)},
                        {1.2, at(0.0, 0.004, 0.0)},
                        {2.5, at(0.0, 0.004, 0.0)}});
        SessionParams p = params(mode);
        Session session(sScene, dev, p);
        bool wasOpen = false;
        Eigen::Vector3d previous = Eigen::Vector3d::Zero();
        double maxStep = 0;
        for (int i = 0; i < 2500; ++i) {
            const Snapshot& s = session.step();
            expectSafe(s, touchX());
            if (!s.gateOpen) {
                ASSERT_EQ(s.force, Eigen::Vector3d::Zero()) << "tick " << i;
            } else if (!wasOpen) {
                EXPECT_LT(s.force.norm(), p.startupThresholdN) << "opening tick " << i;
                EXPECT_EQ(s.tick, p.startupQuietTicks - 1);  // quiet from the first tick
            }
            if (i < 100) {
                EXPECT_TRUE(s.proxy.isApprox(s.probe, 1e-12)) << "free inside, tick " << i;
            }
            if (s.probe.y() < -1e-3) {
                EXPECT_EQ(s.force, Eigen::Vector3d::Zero()) << "outside, tick " << i;
            }
            if (wasOpen) maxStep = std::max(maxStep, (s.force - previous).norm());
            wasOpen = s.gateOpen;
            previous = s.force;
        }
        EXPECT_TRUE(wasOpen);
        // Not trapped inside: the proxy left with the probe and, pressed in again, stays on
        // the skin and pushes out.
        const Snapshot& last = session.step();
        EXPECT_EQ(last.contactCount, 1) << static_cast<int>(mode);
        EXPECT_NEAR(last.proxy.y(), 0.0, 0.5e-3);
        EXPECT_LT(last.force.y(), -0.3);
        // Probe speed <= 18 mm/s: k_max |dx| per tick is 1400 * 18e-6 = 0.025 N; the AVCEC
        // energy term and stiffness changes add to it but never a kick of ~1 N.
        EXPECT_LT(maxStep, 0.5) << static_cast<int>(mode);
    }
}

// (b) D -> 0: the probe presses 2 mm and comes back out to the surface and past it; the force
// goes to zero with D and stays finite.
TEST_F(SessionTest, VanishingDistanceGivesVanishingForce) {
    for (CouplingMode mode : kModes) {
        PathDevice dev({{0, at(-0.002, -0.003, 0.001)},
                        {0.2, at(-0.002, 0.002, 0.001)},
                        {1.2, at(-0.002, -0.001, 0.001)},
                        {2.0, at(-0.002, -0.001, 0.001)}});
        const SessionParams p = params(mode);
        Session session(sScene, dev, p);
        int tiny = 0;
        for (int i = 0; i < 2000; ++i) {
            const Snapshot& s = session.step();
            expectSafe(s, touchX());
            ASSERT_TRUE(std::isfinite(s.stiffness) && std::isfinite(s.distance));
            if (s.gateOpen && s.distance < 2e-5) {
                ++tiny;
                // |F| <= k_max D (1 + 1 / delta): the spring plus the largest energy term.
                EXPECT_LE(s.force.norm(), p.coupling.maxStiffness * s.distance *
                                                  (1 + 1 / p.coupling.bundle.sobelAngle) +
                                              1e-12)
                    << "tick " << i;
            }
        }
        EXPECT_GT(tiny, 3) << "the path should pass through D ~ 0";
    }
}

// (c) The device reports NaN positions for 60 ticks while pressed in: the last good force is
// held through the 2 ms grace and then ramped to zero, reached on the 10th faulty tick (10 ms,
// the session's own fault ramp: this device has no watchdog), finite and bounded throughout; the
// fault is flagged and counted, and rendering resumes afterwards. The same for a finite but
// absurd sample (a driver's garbage, 1e300 m or 20 km away): no ray is cast from it (Embree
// asserts on such rays and took the process down), and its force no longer stays held.
TEST_F(SessionTest, NanSamplesHoldTheLastGoodForceThenRampItToZero) {
    for (double bad : {std::numeric_limits<double>::quiet_NaN(), 1e300, -2e4})
        for (CouplingMode mode : kModes) {
            PathDevice dev({{0, at(0.0, -0.003, 0.0)},
                            {0.3, at(0.0, 0.002, 0.0)},
                            {2.0, at(0.0, 0.002, 0.0)}});
            dev.corrupt(500, 560, bad);
            Session session(sScene, dev, params(mode));
            Eigen::Vector3d before = Eigen::Vector3d::Zero();
            for (int i = 0; i < 1000; ++i) {
                const Snapshot& s = session.step();
                expectSafe(s, touchX());
                if (i == 499) before = s.force;
                if (i >= 500 && i < 560) {
                    const int n = i - 499;  // faulty ticks so far
                    const double scale = n <= 2 ? 1.0 : std::max(0.0, (10.0 - n) / 8.0);
                    EXPECT_TRUE(s.faulted);
                    EXPECT_NE(s.faultFlags & (kFaultNonFinite | kFaultOutOfRange), 0u);
                    EXPECT_LE((s.force - scale * before).norm(), 1e-12) << n;
                    EXPECT_EQ(s.faults, static_cast<std::uint64_t>(n));
                    EXPECT_TRUE(s.probe.allFinite());
                }
                if (i >= 560) {
                    EXPECT_FALSE(s.faulted);
                    EXPECT_EQ(s.faultFlags, 0u);
                    EXPECT_EQ(s.faults, 60u);
                    EXPECT_EQ(s.faultTrips, 1u);
                }
            }
            EXPECT_GT(before.norm(), 0.3);
        }
}

// (d) An empty scene (nothing to touch; a volume only for the volume sources): the proxy is
// the probe and no force is ever sent, in every mode, over thousands of ticks.
TEST_F(SessionTest, EmptySceneIsSafeAndForceFree) {
    auto empty = std::make_shared<Scene>();
    empty->commit();
    auto volumeOnly = std::make_shared<Scene>();
    volumeOnly->setVolume(sVolume->grid);
    volumeOnly->commit();
    for (CouplingMode mode : kModes) {
        PathDevice dev(
            {{0, at(0.0, -0.01, 0.0)}, {1.0, at(0.01, 0.02, -0.01)}, {2.0, at(-0.01, 0.0, 0.01)}});
        Session session(mode == CouplingMode::VC ? empty : volumeOnly, dev, params(mode));
        for (int i = 0; i < 2500; ++i) {
            const Snapshot& s = session.step();
            expectSafe(s, touchX());
            ASSERT_TRUE(s.proxy.isApprox(s.probe, 1e-12) || (s.proxy - s.probe).norm() < 1e-15);
            ASSERT_EQ(s.force, Eigen::Vector3d::Zero());
            ASSERT_EQ(s.contactCount, 0);
        }
    }
}

// No tick allocates: every mode x source, after warm-up, while commands arrive and a
// cross-fade runs.
TEST_F(SessionTest, TicksDoNotAllocate) {
    constexpr std::array<RaySource, 3> kSources = {RaySource::Mesh, RaySource::VolumeFirstHit,
                                                   RaySource::VolumeAccumulate};
    for (CouplingMode mode : kModes) {
        for (RaySource source : kSources) {
            PathDevice dev({{0, at(0.0, -0.003, 0.0)},
                            {0.2, at(0.0, 0.003, 0.0)},
                            {0.5, at(0.01, 0.003, 0.005)},
                            {1.0, at(-0.01, 0.004, -0.005)}});
            SessionParams p = params(mode, source);
            p.coupling.accumulate.sigma = kernels::TransferFunction::step(300, 1e4);
            p.traceCapacity = 64;
            p.crossFadeSeconds = 0.05;
            Session session(sScene, dev, p);
            for (int i = 0; i < 250; ++i) session.step();  // warm-up, into contact

            Command toggle;
            toggle.kind = Command::Kind::SetCoupling;
            toggle.coupling = p.coupling;
            toggle.coupling.mode =
                mode == CouplingMode::AVCEC ? CouplingMode::AVC : CouplingMode::AVCEC;
            Command friction;
            friction.kind = Command::Kind::SetProxy;
            friction.proxy.staticFriction = 0.4;
            friction.proxy.dynamicFriction = 0.2;
            Command control;
            control.kind = Command::Kind::SetPassivityControl;
            control.flag = true;
            Command resetW;
            resetW.kind = Command::Kind::ResetObserver;
            ASSERT_TRUE(session.send(toggle));
            ASSERT_TRUE(session.send(friction));
            ASSERT_TRUE(session.send(control));
            ASSERT_TRUE(session.send(resetW));
            ASSERT_TRUE(session.send(toggle));  // arrives during the fade: pending

            Snapshot trace;
            bool sawFade = false;
            const std::uint64_t before = palp::test::allocationCount();
            for (int i = 0; i < 300; ++i) {
                const Snapshot& s = session.step();
                sawFade = sawFade || s.fading;
                while (session.popTrace(trace)) {
                }
            }
            const std::uint64_t allocations = palp::test::allocationCount() - before;
            EXPECT_EQ(allocations, 0u)
                << "mode " << static_cast<int>(mode) << " source " << static_cast<int>(source);
            EXPECT_TRUE(sawFade);
        }
    }
}

// Switching VC -> AVCEC while pressed above the plate: the stiffness rises 4x. Without a fade
// the force jumps in one tick; with a 0.2 s fade the largest per-tick step is ~1/200 of it.
TEST_F(SessionTest, CrossFadeRemovesTheForceStep) {
    auto run = [&](double fadeSeconds, double& finalForce) {
        PathDevice dev(
            {{0, at(0.0, -0.003, 0.0)}, {0.2, at(0.0, 0.002, 0.0)}, {2.0, at(0.0, 0.002, 0.0)}});
        SessionParams p = params(CouplingMode::VC);
        p.coupling.referenceLength = 0.04;  // plate at L ~ 10 mm: m = 4
        p.coupling.bundle.length = 0.03;
        p.crossFadeSeconds = fadeSeconds;
        Session session(sScene, dev, p);
        for (int i = 0; i < 400; ++i) session.step();
        Command c;
        c.kind = Command::Kind::SetCoupling;
        c.coupling = p.coupling;
        c.coupling.mode = CouplingMode::AVCEC;
        Eigen::Vector3d previous = session.step().force;  // before the switch
        EXPECT_TRUE(session.send(c));
        double maxStep = 0;
        for (int i = 0; i < 400; ++i) {
            const Snapshot& s = session.step();
            maxStep = std::max(maxStep, (s.force - previous).norm());
            previous = s.force;
            EXPECT_EQ(s.mode, CouplingMode::AVCEC);
        }
        finalForce = previous.norm();
        return maxStep;
    };
    double fadedForce = 0, abruptForce = 0;
    const double faded = run(0.2, fadedForce);
    const double abrupt = run(0.0, abruptForce);
    EXPECT_NEAR(fadedForce, abruptForce, 1e-9);  // same end state
    EXPECT_GT(abruptForce, 3.0 * 300 * 0.0015);  // AVCEC really is stiffer here
    EXPECT_GT(abrupt, 1.0);
    EXPECT_LT(faded, abrupt / 50);
    RecordProperty("max_step_faded_N", std::to_string(faded));
    RecordProperty("max_step_abrupt_N", std::to_string(abrupt));
}

}  // namespace
}  // namespace palp::haptics
