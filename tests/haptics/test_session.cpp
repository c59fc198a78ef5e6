// Scene and Session: the per-tick pipeline's physics (VC press, passivity observer), safety at
// every tick (start inside, D -> 0, NaN samples, empty scene), zero allocations per tick,
// cross-faded parameter changes, and a real-time run with a viewer and a producer thread.
#include <gtest/gtest.h>
#include <tbb/task_arena.h>

#include <array>
#include <atomic>
#include <chrono>
#include <cmath>
#include <limits>
#include <thread>
#include <vector>

#include "alloc_counter.h"
#include "palp/base/error.h"
#include "palp/haptics/session.h"
#include "palp/volume/phantom.h"
#include "session_fixtures.h"

namespace palp::haptics {
namespace {

using fixtures::at;
using fixtures::kT;
using fixtures::PathDevice;
using fixtures::touchX;

// The AVC phantom (surface at y = 0, depth +y; rigid plate at y in [10, 12] mm over x, z in
// +-30 mm), 1 mm voxels, skin surface at -500 HU and hard meshes at 500 HU. Built once.
class SessionTest : public ::testing::Test {
  protected:
    static void SetUpTestSuite() { fixtures::buildAvcScene(sVolume, sScene); }
    static void TearDownTestSuite() {
        sScene.reset();
        delete sVolume;
        sVolume = nullptr;
    }
    static SessionParams params(CouplingMode mode, RaySource source = RaySource::VolumeFirstHit) {
        SessionParams p;
        p.coupling.mode = mode;
        p.coupling.source = source;
        p.coupling.baseStiffness = 300;
        p.coupling.maxStiffness = 1400;
        p.proxy.staticFriction = 0;
        p.proxy.dynamicFriction = 0;
        return p;
    }
    static volume::Volume* sVolume;
    static std::shared_ptr<Scene> sScene;
};
volume::Volume* SessionTest::sVolume = nullptr;
std::shared_ptr<Scene> SessionTest::sScene;

constexpr std::array<CouplingMode, 3> kModes = {CouplingMode::VC, CouplingMode::AVC,
                                                CouplingMode::AVCEC};

// Every tick: finite force, within the device maximum.
void expectSafe(const Snapshot& s, const DeviceSpec& spec) {
    ASSERT_TRUE(s.force.allFinite()) << "tick " << s.tick;
    ASSERT_LE(s.force.norm(), spec.maxForceN * (1 + 1e-12)) << "tick " << s.tick;
}

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
// held (finite, bounded), the fault is flagged and counted, and rendering resumes afterwards.
// The same for a finite but absurd sample (a driver's garbage, 1e300 m or 20 km away): no ray
// is cast from it (Embree asserts on such rays and took the process down).
TEST_F(SessionTest, NanSamplesHoldTheLastGoodForce) {
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
                    EXPECT_TRUE(s.faulted);
                    EXPECT_EQ(s.force, before);
                    EXPECT_EQ(s.faults, static_cast<std::uint64_t>(i - 499));
                    EXPECT_TRUE(s.probe.allFinite());
                }
                if (i >= 560) {
                    EXPECT_FALSE(s.faulted);
                    EXPECT_EQ(s.faults, 60u);
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

// The passivity observer: W(n) = -T sum F.v over the forces sent, equal to the spring's
// stored energy 1/2 k D^2 at the bottom of a press (to the sampling error), never negative
// for a VC spring, and reset by the ResetObserver command.
TEST_F(SessionTest, PassivityObserverBooksTheSpringEnergy) {
    PathDevice dev({{0, at(0.0, -0.002, 0.0)},
                    {0.4, at(0.0, 0.003, 0.0)},
                    {0.6, at(0.0, 0.003, 0.0)},
                    {1.0, at(0.0, -0.002, 0.0)},
                    {1.5, at(0.0, -0.002, 0.0)}});
    Session session(sScene, dev, params(CouplingMode::VC));
    double w = 0;
    for (int i = 0; i < 1500; ++i) {
        const Snapshot& s = session.step();
        w -= kT * s.force.dot(dev.last().velocity);
        EXPECT_NEAR(s.observerEnergy, w, 1e-12 + 1e-9 * std::abs(w)) << "tick " << i;
        EXPECT_GE(s.observerEnergy, -1e-6) << "tick " << i;
        if (i == 500) {
            const double stored = s.couplingEnergy;
            EXPECT_GT(stored, 1e-4);
            EXPECT_NEAR(s.observerEnergy, stored, 0.03 * stored);
        }
    }
    // Back in free space: the spring gave its energy back (up to the sampling error).
    EXPECT_NEAR(session.step().observerEnergy, 0.0, 2e-5);
    Command c;
    c.kind = Command::Kind::ResetObserver;
    ASSERT_TRUE(session.send(c));
    EXPECT_EQ(session.step().observerEnergy, 0.0);
}

// The observer books the force actually sent: while the start-up gate holds the force at zero
// nothing is exchanged with the hand, however hard the (unsent) coupling pulls; and a clamped
// force is booked as clamped.
TEST_F(SessionTest, PassivityObserverBooksOnlyTheForceSent) {
    PathDevice dev({{0, at(0.0, -0.002, 0.0)},
                    {0.4, at(0.0, 0.003, 0.0)},
                    {0.6, at(0.0, 0.003, 0.0)},
                    {1.0, at(0.0, -0.002, 0.0)}});
    SessionParams p = params(CouplingMode::VC);
    p.startupQuietTicks = 1000000;  // never enough quiet ticks: the gate stays shut
    Session gated(sScene, dev, p);
    for (int i = 0; i < 1000; ++i) {
        const Snapshot& s = gated.step();
        ASSERT_EQ(s.force.norm(), 0.0) << "tick " << i;
        ASSERT_EQ(s.observerEnergy, 0.0) << "tick " << i;
    }

    PathDevice dev2({{0, at(0.0, -0.002, 0.0)}, {0.4, at(0.0, 0.012, 0.0)}});
    SessionParams hard = params(CouplingMode::VC);
    hard.coupling.baseStiffness = 1400;  // 14 mm deep: far past the device's maximum force
    Session clamped(sScene, dev2, hard);
    double w = 0;
    int clampedTicks = 0;
    for (int i = 0; i < 400; ++i) {
        const Snapshot& s = clamped.step();
        w -= kT * s.force.dot(dev2.last().velocity);
        clampedTicks += s.clamped ? 1 : 0;
        ASSERT_NEAR(s.observerEnergy, w, 1e-12 + 1e-9 * std::abs(w)) << "tick " << i;
    }
    EXPECT_GT(clampedTicks, 0);
}

// The device's stability limit: a coupling asking for more than the Touch X's 1480 N/m is
// rendered at 1480 N/m (at construction and through send()), flagged on the session, in
// params() and on every snapshot; one within the limit is untouched.
TEST_F(SessionTest, StiffnessAboveTheDeviceLimitIsClamped) {
    const double limit = touchX().maxStiffnessNpm;
    ASSERT_GT(limit, 0);

    CouplingParams c = params(CouplingMode::VC).coupling;
    c.baseStiffness = 2 * limit;
    c.maxStiffness = 3 * limit;
    const double period = 1e-3;  // the sampled-wall bound 0.9 * 2 b / T = 5400 N/m: not binding
    EXPECT_TRUE(limitStiffnessToDevice(c, touchX(), period));
    EXPECT_EQ(c.maxStiffness, limit);
    EXPECT_EQ(c.baseStiffness, limit);
    EXPECT_FALSE(limitStiffnessToDevice(c, touchX(), period));  // already within: unchanged
    DeviceSpec unlimited = touchX();
    unlimited.maxStiffnessNpm = 0;  // no limit known
    unlimited.maxDampingNspm = 0;
    c.maxStiffness = 3 * limit;
    EXPECT_FALSE(limitStiffnessToDevice(c, unlimited, period));
    EXPECT_EQ(c.maxStiffness, 3 * limit);
    // A slow servo rate: Colgate's sampled-wall bound (k < 2 b / T, 10 % inside) binds first.
    CouplingParams slow = params(CouplingMode::VC).coupling;
    slow.maxStiffness = limit;
    const double slowPeriod = 1e-2;
    const double wall = 0.9 * 2.0 * touchX().maxDampingNspm / slowPeriod;
    ASSERT_LT(wall, limit);
    EXPECT_TRUE(limitStiffnessToDevice(slow, touchX(), slowPeriod));
    EXPECT_EQ(slow.maxStiffness, wall);
    EXPECT_LE(slow.baseStiffness, wall);
    EXPECT_FALSE(limitStiffnessToDevice(slow, touchX(), 0.0));  // no period: device limit only

    // VC at twice the limit, pressed ~2 mm: F = limit D, not 2 limit D.
    PathDevice dev({{0, at(0.004, -0.004, 0.003)},
                    {0.3, at(0.004, 0.002, 0.003)},
                    {1.0, at(0.004, 0.002, 0.003)}});
    SessionParams p = params(CouplingMode::VC);
    p.coupling.baseStiffness = 2 * limit;
    p.coupling.maxStiffness = 3 * limit;
    p.crossFadeSeconds = 0;
    Session session(sScene, dev, p);
    EXPECT_TRUE(session.stiffnessLimited());
    EXPECT_EQ(session.params().coupling.maxStiffness, limit);
    EXPECT_EQ(session.params().coupling.baseStiffness, limit);
    Snapshot s;
    for (int i = 0; i < 600; ++i) {
        s = session.step();
        ASSERT_TRUE(s.stiffnessLimited) << "tick " << i;
        ASSERT_LE(s.stiffness, limit) << "tick " << i;
    }
    EXPECT_EQ(s.contactCount, 1);
    EXPECT_GT(s.distance, 1e-3);
    EXPECT_NEAR(s.force.norm(), limit * s.distance, 1e-9);
    EXPECT_FALSE(s.clamped);  // 1480 N/m x ~2 mm is below the 7.9 N maximum

    // Through send(): back within the limit (flag off), then AVC whose k_max is above it.
    Command within;
    within.kind = Command::Kind::SetCoupling;
    within.coupling = params(CouplingMode::VC).coupling;  // 300 / 1400 N/m
    ASSERT_TRUE(session.send(within));
    s = session.step();
    EXPECT_FALSE(s.stiffnessLimited);
    EXPECT_EQ(s.stiffness, 300);
    Command avc;
    avc.kind = Command::Kind::SetCoupling;
    avc.coupling = params(CouplingMode::AVC).coupling;
    avc.coupling.referenceLength = 0.08;  // plate at ~10 mm: m = 8, k_s m = 2400 N/m
    avc.coupling.maxMultiplier = 8;
    avc.coupling.maxStiffness = 2400;
    avc.coupling.bundle.length = 0.03;
    ASSERT_TRUE(session.send(avc));
    double largest = 0;
    for (int i = 0; i < 400; ++i) {
        s = session.step();
        largest = std::max(largest, s.stiffness);
        ASSERT_LE(s.stiffness, limit + 1e-9) << "tick " << i;
    }
    EXPECT_TRUE(s.stiffnessLimited);
    EXPECT_EQ(s.mode, CouplingMode::AVC);
    EXPECT_GT(largest, 0.99 * limit);  // the limit really binds above the plate
}

// A device whose position is a zero-order hold (updated every kHold ticks) of a sinusoidal
// press y(t) = -A cos(2 pi f t) into the skin at y = 0, while its velocity is exact: the wall
// feels the position late, pushes less on the way in than on the way out, and so returns more
// energy than it received (an active, energy-generating loop).
class HeldPositionDevice final : public Device {
  public:
    static constexpr int kHold = 3;
    static constexpr double kAmplitude = 0.002, kFrequency = 2;
    DeviceState read() noexcept override {
        const double t = static_cast<double>(mTick) * kT;
        if (mTick % kHold == 0) mHeld = position(t);
        DeviceState s;
        s.position = mHeld;
        s.velocity =
            at(0, 2 * M_PI * kFrequency * kAmplitude * std::sin(2 * M_PI * kFrequency * t), 0);
        s.timestampSeconds = t;
        ++mTick;
        mLast = s;
        mTrue = position(t);
        return s;
    }
    void write(const Eigen::Vector3d&) noexcept override {}
    const DeviceSpec& spec() const noexcept override { return omega3(); }
    // A device with room to dissipate: 20 N s/m of rendered damping (the Touch X's 3 N s/m
    // cannot absorb this wall's surplus, 1000 N/m x 1 ms, as fast as it comes back).
    static const DeviceSpec& omega3() {
        const DeviceSpec* s = findDeviceSpec("Force Dimension omega.3");
        EXPECT_NE(s, nullptr);
        return *s;
    }
    static Eigen::Vector3d position(double t) {
        return at(0.004, -kAmplitude * std::cos(2 * M_PI * kFrequency * t), 0.003);
    }
    const DeviceState& last() const { return mLast; }
    const Eigen::Vector3d& truePosition() const { return mTrue; }

  private:
    std::uint64_t mTick = 0;
    Eigen::Vector3d mHeld{Eigen::Vector3d::Zero()}, mTrue{Eigen::Vector3d::Zero()};
    DeviceState mLast;
};

// The passivity controller inside Session: on the held-position wall the observer's W goes
// negative without the controller (the energy the wall generated, estimated independently from
// the hold error, is what W lacks once the spring is relaxed); with the controller W stays at
// or above zero at every tick, the added damping stays within the device's maxDampingNspm, and
// the force stays finite and bounded by the spring plus that damping.
TEST_F(SessionTest, PassivityControllerKeepsAnActiveWallPassive) {
    constexpr double k = 1000;    // N/m; the omega.3 renders up to 14500
    constexpr int kTicks = 3000;  // six press cycles
    struct Run {
        double minW = 0, finalW = 0, generated = 0, maxAlpha = 0, maxForce = 0, maxBound = 0;
        int dampedTicks = 0;
        bool finite = true;
    };
    auto run = [&](bool control) {
        HeldPositionDevice dev;
        SessionParams p = params(CouplingMode::VC);
        p.coupling.baseStiffness = k;
        p.coupling.maxStiffness = k;
        p.passivityControl = control;
        Session session(sScene, dev, p);
        Run r;
        for (int i = 0; i < kTicks; ++i) {
            const Snapshot& s = session.step();
            r.finite = r.finite && s.force.allFinite() && std::isfinite(s.observerEnergy);
            r.minW = std::min(r.minW, s.observerEnergy);
            r.maxAlpha = std::max(r.maxAlpha, s.addedDamping);
            r.dampedTicks += s.addedDamping > 0 ? 1 : 0;
            r.maxForce = std::max(r.maxForce, s.force.norm());
            // Spring on the held probe plus the controller's damping on the true velocity.
            const double v = dev.last().velocity.norm();
            r.maxBound = std::max(r.maxBound, s.force.norm() - k * s.distance - s.addedDamping * v);
            // The hold error's power: the spring k (y - y_held) pushes with the true motion.
            if (s.contactCount > 0 && s.gateOpen) {
                r.generated += kT * k * (dev.truePosition().y() - dev.last().position.y()) *
                               dev.last().velocity.y();
            }
            r.finalW = s.observerEnergy;
        }
        return r;
    };
    const Run passive = run(false);
    const Run controlled = run(true);
    ASSERT_GT(passive.generated, 0);
    // Without the controller: the probe ends outside (spring relaxed), W is about minus the
    // energy the hold generated.
    EXPECT_LT(passive.finalW, -0.5 * passive.generated);
    EXPECT_LT(passive.minW, -0.5 * passive.generated);
    EXPECT_EQ(passive.dampedTicks, 0);
    // With it: never negative (to rounding), damping within the device's cap, force bounded.
    EXPECT_GE(controlled.minW, -1e-12);
    EXPECT_GT(controlled.dampedTicks, 0);
    EXPECT_LE(controlled.maxAlpha, HeldPositionDevice::omega3().maxDampingNspm);
    EXPECT_TRUE(controlled.finite);
    EXPECT_LE(controlled.maxForce, HeldPositionDevice::omega3().maxForceN);
    EXPECT_LE(controlled.maxBound, 1e-9);
    RecordProperty("W_final_without_J", std::to_string(passive.finalW));
    RecordProperty("W_min_with_J", std::to_string(controlled.minW));
    RecordProperty("generated_J", std::to_string(passive.generated));
}

// A device that stalls the servo thread for 15 ms every 50th tick, so the real-time loop
// overruns and skips deadlines (its nominal clock then runs ahead of ticks x T).
class StallingDevice final : public Device {
  public:
    DeviceState read() noexcept override {
        if (mTick++ % 50 == 25) std::this_thread::sleep_for(std::chrono::milliseconds(15));
        DeviceState s;
        s.position = at(0.0, -0.01, 0.0);  // in free space
        return s;
    }
    void write(const Eigen::Vector3d&) noexcept override {}
    const DeviceSpec& spec() const noexcept override { return touchX(); }

  private:
    std::atomic<std::uint64_t> mTick{0};
};

// Snapshot time never goes backwards across step / start / stop / step / start / stop / step,
// also when the real-time runs skipped deadlines; every tick is in the trace once, in order.
TEST_F(SessionTest, TimeIsMonotonicAcrossRunsAndSteps) {
    StallingDevice dev;
    SessionParams p = params(CouplingMode::VC);
    p.traceCapacity = 1u << 14;
    p.servo.priority = 0;
    Session session(sScene, dev, p);
    std::uint64_t skipped = 0;
    auto realtime = [&](std::uint64_t ticks) {
        const std::uint64_t before = session.stats().ticks;
        session.start();
        for (int i = 0; i < 5000 && session.stats().ticks < before + ticks; ++i)
            std::this_thread::sleep_for(std::chrono::milliseconds(1));
        session.stop();
        skipped = session.stats().skipped;
    };
    for (int i = 0; i < 100; ++i) session.step();
    realtime(80);
    EXPECT_GT(skipped, 0u) << "the stalls must make the loop skip deadlines";
    const double lastRun = session.latest().timeSeconds;
    const Snapshot& after = session.step();
    EXPECT_NEAR(after.timeSeconds, lastRun + kT, 1e-12);
    for (int i = 0; i < 49; ++i) session.step();
    realtime(80);
    for (int i = 0; i < 10; ++i) session.step();

    Snapshot t;
    std::uint64_t count = 0;
    double previous = -1;
    while (session.popTrace(t)) {
        ASSERT_EQ(t.tick, count) << "trace in order, none lost";
        ASSERT_GT(t.timeSeconds, previous) << "tick " << t.tick;
        ASSERT_GE(t.timeSeconds - previous, kT * (1 - 1e-9)) << "tick " << t.tick;
        previous = t.timeSeconds;
        ++count;
    }
    EXPECT_EQ(session.traceDropped(), 0u);
    EXPECT_GT(count, 100u + 80 + 50 + 80 + 10 - 1);
}

// A real-time run: a viewer thread reads latest() and the trace, a producer thread sends
// commands, the controlling thread starts and stops. Every published snapshot is complete
// (finite, bounded), latest() never goes back in time, and the trace holds every tick
// exactly once (popped + dropped = ticks).
TEST_F(SessionTest, RealTimeRunWithViewerAndProducer) {
    PathDevice dev(
        {{0, at(0.0, -0.003, 0.0)}, {0.15, at(0.0, 0.002, 0.0)}, {0.4, at(0.005, 0.002, 0.0)}});
    SessionParams p = params(CouplingMode::AVCEC);
    p.traceCapacity = 1024;
    p.crossFadeSeconds = 0.02;
    p.servo.priority = 0;  // no SCHED_FIFO request in a test
    Session session(sScene, dev, p);
    std::atomic<bool> done{false};
    std::uint64_t popped = 0, lastTraceTick = 0, viewerReads = 0;
    bool traceInOrder = true, viewerMonotonic = true, allSafe = true;
    std::thread viewer([&] {
        std::uint64_t lastSeen = 0;
        Snapshot t;
        while (!done.load(std::memory_order_acquire)) {
            const Snapshot& s = session.latest();
            if (s.tick < lastSeen) viewerMonotonic = false;
            lastSeen = s.tick;
            if (!s.force.allFinite() || s.force.norm() > touchX().maxForceN) allSafe = false;
            ++viewerReads;
            while (session.popTrace(t)) {
                if (popped > 0 && t.tick <= lastTraceTick) traceInOrder = false;
                lastTraceTick = t.tick;
                ++popped;
            }
            session.latestRays();
            std::this_thread::sleep_for(std::chrono::microseconds(200));
        }
    });
    std::atomic<int> sent{0};
    std::thread producer([&] {
        Command c;
        c.kind = Command::Kind::SetCoupling;
        c.coupling = p.coupling;
        for (int i = 0; !done.load(std::memory_order_acquire); ++i) {
            c.kind = static_cast<Command::Kind>(i % 4);
            c.coupling.mode = kModes[static_cast<std::size_t>(i % 3)];
            c.flag = (i % 2) == 0;
            if (session.send(c)) sent.fetch_add(1);
            std::this_thread::sleep_for(std::chrono::milliseconds(3));
        }
    });
    session.start();
    EXPECT_TRUE(session.running());
    EXPECT_FALSE(session.realtime().message.empty());
    std::this_thread::sleep_for(std::chrono::milliseconds(300));
    session.stop();
    EXPECT_FALSE(session.running());
    done.store(true, std::memory_order_release);
    viewer.join();
    producer.join();
    Snapshot t;
    while (session.popTrace(t)) {
        if (popped > 0 && t.tick <= lastTraceTick) traceInOrder = false;
        lastTraceTick = t.tick;
        ++popped;
    }
    const ServoStats stats = session.stats();
    EXPECT_GT(stats.ticks, 30u);
    EXPECT_EQ(popped + session.traceDropped(), stats.ticks);
    EXPECT_TRUE(traceInOrder);
    EXPECT_TRUE(viewerMonotonic);
    EXPECT_TRUE(allSafe);
    EXPECT_GT(viewerReads, 10u);
    EXPECT_GT(sent.load(), 10);
    EXPECT_EQ(session.latest().tick + 1, stats.ticks);
    // Offline steps continue where the run stopped.
    const Snapshot& next = session.step();
    EXPECT_EQ(next.tick, stats.ticks);
}

}  // namespace
}  // namespace palp::haptics
