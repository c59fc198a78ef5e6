// Session's passivity: the observer books the spring's energy and only the force sent, the
// controller keeps an active (held-position) wall passive, and a coupling stiffer than the
// device's stability limit is rendered at that limit.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <string>

#include "palp/haptics/session.h"
#include "session_fixtures.h"
#include "session_test_fixture.h"

namespace palp::haptics {
namespace {

using namespace sfix;  // SessionTest, kModes, expectSafe, at, kT, PathDevice, touchX

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

}  // namespace
}  // namespace palp::haptics
