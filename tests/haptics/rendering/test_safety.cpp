#include <gtest/gtest.h>

#include <limits>

#include "palp/haptics/rendering/safety.h"

namespace palp::haptics {
namespace {

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();
constexpr double kInf = std::numeric_limits<double>::infinity();

TEST(ClampForce, KeepsSmallForces) {
    const Eigen::Vector3d f(1, -2, 0.5);
    EXPECT_EQ(clampForce(f, 3.3), f);
}

TEST(ClampForce, ScalesLargeForcesPreservingDirection) {
    const Eigen::Vector3d f(30, -40, 0);  // 50 N
    const Eigen::Vector3d c = clampForce(f, 3.3);
    EXPECT_NEAR(c.norm(), 3.3, 1e-12);
    EXPECT_NEAR(c.normalized().dot(f.normalized()), 1.0, 1e-12);
}

TEST(ClampForce, NonFiniteOrZeroLimitGivesZero) {
    EXPECT_EQ(clampForce(Eigen::Vector3d(kNaN, 0, 0), 3.3), Eigen::Vector3d::Zero());
    EXPECT_EQ(clampForce(Eigen::Vector3d(kInf, 0, 0), 3.3), Eigen::Vector3d::Zero());
    EXPECT_EQ(clampForce(Eigen::Vector3d(1, 0, 0), 0.0), Eigen::Vector3d::Zero());
}

TEST(ForceGuard, HoldsLastGoodForceAndFlags) {
    ForceGuard guard;
    EXPECT_EQ(guard.filter(Eigen::Vector3d(kNaN, 0, 0)), Eigen::Vector3d::Zero());
    EXPECT_TRUE(guard.faulted());
    guard.clearFault();
    EXPECT_FALSE(guard.faulted());

    const Eigen::Vector3d good(0.5, 1.0, -0.25);
    EXPECT_EQ(guard.filter(good), good);
    EXPECT_FALSE(guard.faulted());
    EXPECT_EQ(guard.filter(Eigen::Vector3d(0, kInf, 0)), good);
    EXPECT_EQ(guard.filter(Eigen::Vector3d(0, 0, -kInf)), good);
    EXPECT_TRUE(guard.faulted());
    EXPECT_EQ(guard.faultCount(), 3u);
    const Eigen::Vector3d next(1, 1, 1);
    EXPECT_EQ(guard.filter(next), next);
    EXPECT_TRUE(guard.faulted());  // sticky until cleared
    EXPECT_EQ(guard.lastGood(), next);
}

TEST(StartupGate, WaitsForQuietTicks) {
    StartupGate gate(/*thresholdN=*/0.1, /*quietTicks=*/5);
    const Eigen::Vector3d loud(2, 0, 0);
    const Eigen::Vector3d quiet(0.05, 0, 0);
    // Probe starts inside an object: large force, nothing sent.
    for (int i = 0; i < 10; ++i) EXPECT_EQ(gate.filter(loud), Eigen::Vector3d::Zero());
    // Four quiet ticks, then a loud one restarts the count.
    for (int i = 0; i < 4; ++i) EXPECT_EQ(gate.filter(quiet), Eigen::Vector3d::Zero());
    EXPECT_EQ(gate.filter(loud), Eigen::Vector3d::Zero());
    EXPECT_EQ(gate.filter(Eigen::Vector3d(kNaN, 0, 0)), Eigen::Vector3d::Zero());
    for (int i = 0; i < 4; ++i) EXPECT_EQ(gate.filter(quiet), Eigen::Vector3d::Zero());
    EXPECT_FALSE(gate.open());
    // The fifth consecutive quiet tick opens the gate; it stays open for loud forces.
    EXPECT_EQ(gate.filter(quiet), quiet);
    EXPECT_TRUE(gate.open());
    EXPECT_EQ(gate.filter(loud), loud);
    gate.reset();
    EXPECT_FALSE(gate.open());
    EXPECT_EQ(gate.filter(loud), Eigen::Vector3d::Zero());
}

TEST(StartupGate, ZeroTicksIsOpen) {
    StartupGate gate(0.1, 0);
    EXPECT_TRUE(gate.open());
    EXPECT_EQ(gate.filter(Eigen::Vector3d(3, 0, 0)), Eigen::Vector3d(3, 0, 0));
}

TEST(CrossFade, LinearOverGivenTicks) {
    CrossFade k(100.0);
    EXPECT_EQ(k.value(), 100.0);
    EXPECT_FALSE(k.fading());
    k.setTarget(500.0, 4);
    EXPECT_TRUE(k.fading());
    EXPECT_DOUBLE_EQ(k.value(), 100.0);
    EXPECT_DOUBLE_EQ(k.step(), 200.0);
    EXPECT_DOUBLE_EQ(k.step(), 300.0);
    EXPECT_DOUBLE_EQ(k.step(), 400.0);
    EXPECT_EQ(k.step(), 500.0);  // exactly the target at the end
    EXPECT_FALSE(k.fading());
    EXPECT_EQ(k.step(), 500.0);
}

TEST(CrossFade, RetargetMidFadeStartsFromCurrentValue) {
    CrossFade k(0.0);
    k.setTarget(10.0, 10);
    for (int i = 0; i < 5; ++i) k.step();
    EXPECT_DOUBLE_EQ(k.value(), 5.0);
    k.setTarget(0.0, 5);
    EXPECT_DOUBLE_EQ(k.step(), 4.0);  // no jump
    k.setTarget(7.0, 0);
    EXPECT_EQ(k.value(), 7.0);
    EXPECT_EQ(k.target(), 7.0);
}

}  // namespace
}  // namespace palp::haptics
