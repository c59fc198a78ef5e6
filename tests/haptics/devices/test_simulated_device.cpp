#include <gtest/gtest.h>

#include <algorithm>

#include "alloc_counter.h"
#include "palp/haptics/devices/simulated_device.h"
#include "palp/haptics/rendering/passivity.h"

namespace palp::haptics {
namespace {

constexpr double kT = 1e-3;

const DeviceSpec& touch() {
    const DeviceSpec* s = findDeviceSpec("3D Systems Touch");
    EXPECT_NE(s, nullptr);
    return *s;
}

TEST(PressTrajectory, SmoothPressHoldAndReturn) {
    PressTrajectory p;
    p.start = Eigen::Vector3d(0.01, 0.0, 0.02);
    Eigen::Vector3d x;
    Eigen::Vector3d v;
    p.sample(0.0, x, v);
    EXPECT_TRUE(x.isApprox(p.start));
    EXPECT_EQ(v, Eigen::Vector3d::Zero());
    p.sample(0.25, x, v);  // half way down, fastest
    EXPECT_NEAR(x.z(), 0.02 - 0.005, 1e-12);
    EXPECT_LT(v.z(), 0.0);
    p.sample(0.75, x, v);  // holding
    EXPECT_NEAR(x.z(), 0.01, 1e-12);
    EXPECT_EQ(v, Eigen::Vector3d::Zero());
    p.sample(1.25, x, v);  // half way up
    EXPECT_NEAR(x.z(), 0.015, 1e-12);
    EXPECT_GT(v.z(), 0.0);
    p.sample(5.0, x, v);
    EXPECT_TRUE(x.isApprox(p.start));
}

TEST(SimulatedDevice, FreeHandFollowsThePress) {
    SimulatedDevice dev(touch(), PressTrajectory{}, HandModel{}, kT);
    DeviceState s;
    for (int n = 0; n < 1000; ++n) s = dev.read();  // end of the hold
    EXPECT_NEAR(s.timestampSeconds, 1.0, 1e-9);
    EXPECT_NEAR(s.position.z(), -0.01, 1e-4);
    EXPECT_NEAR(s.velocity.norm(), 0.0, 1e-3);
    for (int n = 0; n < 1500; ++n) s = dev.read();  // back up and settled
    EXPECT_NEAR(s.position.z(), 0.0, 1e-4);
}

TEST(SimulatedDevice, WallForceStopsTheHandAtTheStaticEquilibrium) {
    const HandModel hand;
    const double kWall = 1000.0;  // N/m, below the Touch's maximum stiffness
    const double zWall = -0.005;
    SimulatedDevice dev(touch(), PressTrajectory{}, hand, kT);
    PassivityController observer(kT, /*enabled=*/false);
    DeviceState s;
    double minEnergy = 0.0;
    double zAtHoldEnd = 0.0;
    for (int n = 1; n <= 2500; ++n) {
        s = dev.read();
        const double pen = std::max(0.0, zWall - s.position.z());
        const Eigen::Vector3d f(0.0, 0.0, kWall * pen);
        dev.write(f);
        observer.update(dev.appliedForce(), s.velocity);
        minEnergy = std::min(minEnergy, observer.energy());
        if (n == 1000) zAtHoldEnd = s.position.z();
    }
    // k_h (z_target - z) + k_wall (z_wall - z) = 0.
    const double zEq = (hand.stiffnessNpm * -0.01 + kWall * zWall) / (hand.stiffnessNpm + kWall);
    EXPECT_NEAR(zAtHoldEnd, zEq, 1e-4);
    // The hand's damping keeps the sampled wall passive over the press-and-release cycle (the
    // observer sees W >= 0 throughout), and the wall is relaxed at the end.
    EXPECT_GE(minEnergy, -1e-9);
    EXPECT_NEAR(s.position.z(), 0.0, 1e-4);
}

TEST(SimulatedDevice, WriteClampsAndDoesNotAllocate) {
    SimulatedDevice dev(touch(), PressTrajectory{}, HandModel{}, kT);
    const std::uint64_t before = test::allocationCount();
    Device& d = dev;
    double sum = 0.0;
    for (int n = 0; n < 1000; ++n) {
        sum += d.read().position.z();
        d.write(Eigen::Vector3d(0, 0, 100.0));
    }
    EXPECT_EQ(test::allocationCount(), before);
    EXPECT_NEAR(dev.appliedForce().norm(), touch().maxForceN, 1e-12);
    EXPECT_TRUE(std::isfinite(sum));
}

}  // namespace
}  // namespace palp::haptics
