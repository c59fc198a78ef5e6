#pragma once
// What the device-bridge tests share (test_udp_device.cpp, test_udp_faults.cpp): the AVC
// phantom scene (surface y = 0) built once per suite, a loopback UdpDevice's parameters and
// address, and the remote hand's press.
#include <gtest/gtest.h>

#include <cstdint>
#include <memory>
#include <string>

#include "palp/haptics/devices/bridge_protocol.h"
#include "palp/haptics/devices/udp_device.h"
#include "palp/haptics/session.h"
#include "session_fixtures.h"

namespace palp::haptics::udp_fixtures {

inline constexpr double kStiffness = 300;  // N/m, VC
inline constexpr double kDepth = 3e-3;     // m below the surface y = 0 at the hold

/// The suites' scene, built once per suite.
class UdpSceneTest : public ::testing::Test {
  protected:
    static void SetUpTestSuite() { fixtures::buildAvcScene(sVolume, sScene); }
    static void TearDownTestSuite() {
        sScene.reset();
        delete sVolume;
        sVolume = nullptr;
    }
    /// A UdpDevice on any free loopback port.
    static UdpDeviceParams deviceParams() {
        UdpDeviceParams p;
        p.listen = "127.0.0.1:0";
        return p;
    }
    inline static volume::Volume* sVolume = nullptr;
    inline static std::shared_ptr<Scene> sScene;
};

/// The remote hand's press: from 4 mm above the surface down to kDepth below it in 0.3 s, then
/// held (kinematic: the force does not move it). Sample @p i is at i kT.
inline bridge::StateMessage pressState(std::uint64_t i) {
    const double t = static_cast<double>(i) * fixtures::kT;
    const double y0 = -4e-3, y1 = kDepth, t1 = 0.3;
    bridge::StateMessage m;
    m.sequence = i + 1;
    m.timeNs = i * 1000000ull + 5;
    m.position = {0.004, t < t1 ? y0 + (y1 - y0) * t / t1 : y1, 0.003};
    m.velocity = {0, t < t1 ? (y1 - y0) / t1 : 0.0, 0};
    return m;
}

/// "127.0.0.1:port" of @p d.
inline std::string address(const UdpDevice& d) { return "127.0.0.1:" + std::to_string(d.port()); }

}  // namespace palp::haptics::udp_fixtures
