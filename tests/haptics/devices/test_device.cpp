#include <gtest/gtest.h>

#include "palp/haptics/devices/device.h"

namespace palp::haptics {
namespace {

TEST(DeviceSpec, TableIsConsistent) {
    ASSERT_GE(deviceSpecs().size(), 5u);
    for (const DeviceSpec& s : deviceSpecs()) {
        SCOPED_TRACE(std::string(s.name));
        EXPECT_FALSE(s.name.empty());
        EXPECT_GT(s.maxForceN, 0.0);
        EXPECT_GT(s.maxContinuousForceN, 0.0);
        EXPECT_LE(s.maxContinuousForceN, s.maxForceN);
        EXPECT_GT(s.maxStiffnessNpm, 0.0);
        EXPECT_GT(s.maxDampingNspm, 0.0);
        // Desktop devices: every workspace edge between 5 cm and 50 cm, centred on the origin.
        const Eigen::Vector3d size = s.workspace.size();
        EXPECT_GT(size.minCoeff(), 0.05);
        EXPECT_LT(size.maxCoeff(), 0.5);
        EXPECT_TRUE(s.workspace.contains(Eigen::Vector3d::Zero()));
        EXPECT_EQ(findDeviceSpec(s.name), &s);
    }
}

TEST(DeviceSpec, KnownFigures) {
    const DeviceSpec* touch = findDeviceSpec("3D Systems Touch");
    ASSERT_NE(touch, nullptr);
    EXPECT_DOUBLE_EQ(touch->maxForceN, 3.3);
    EXPECT_NEAR(touch->workspace.size().x(), 0.160, 1e-12);
    const DeviceSpec* premium = findDeviceSpec("Phantom Premium 1.5");
    ASSERT_NE(premium, nullptr);
    EXPECT_NEAR(premium->workspace.size().x(), 0.381, 1e-12);
    EXPECT_EQ(findDeviceSpec("no such device"), nullptr);
}

TEST(WorkspaceBox, Contains) {
    const WorkspaceBox box{Eigen::Vector3d(-1, -1, -1), Eigen::Vector3d(1, 2, 3)};
    EXPECT_TRUE(box.contains(Eigen::Vector3d(1, 2, 3)));
    EXPECT_FALSE(box.contains(Eigen::Vector3d(0, 0, 3.1)));
    EXPECT_TRUE(box.size().isApprox(Eigen::Vector3d(2, 3, 4)));
}

}  // namespace
}  // namespace palp::haptics
