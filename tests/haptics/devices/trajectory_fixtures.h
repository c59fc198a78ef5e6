#pragma once
// Shared by the trajectory and device-log tests (test_trajectory.cpp, test_playback_device.cpp):
// the servo period and the device their simulated hands run on.
#include <gtest/gtest.h>

#include "palp/haptics/devices/device.h"

namespace palp::haptics::tfix {

inline constexpr double kT = 1e-3;  // servo period, s

/// The 3D Systems Touch spec from palp's table.
inline const DeviceSpec& touch() {
    const DeviceSpec* s = findDeviceSpec("3D Systems Touch");
    EXPECT_NE(s, nullptr);
    return *s;
}

}  // namespace palp::haptics::tfix
