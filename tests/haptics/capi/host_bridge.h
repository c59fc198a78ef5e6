#pragma once
// A C++ SimulatedDevice behind the C API's host-device callbacks, as a host's bridge would do
// (test_c_api_host, test_c_api_study); switches to go silent, send NaN or absurd positions.
#include <Eigen/Core>
#include <cstdint>
#include <limits>

#include "palp/haptics/devices/simulated_device.h"
#include "palp/palp.h"

namespace palp::test {

/// A C++ SimulatedDevice behind the C callbacks (what a host's bridge would do).
struct Bridge {
    palp::haptics::SimulatedDevice* device;
    std::uint64_t sequence = 0;
    bool silent = false;
    bool nan = false;
    int absurd = 0;  // 1: x = 20 km, 2: y = 1e300 m (finite, far beyond any device)
};

inline int bridgeRead(void* user, palp_device_state* s) {
    auto* b = static_cast<Bridge*>(user);
    if (b->silent) return 1;
    const palp::haptics::DeviceState d = b->device->read();
    for (int i = 0; i < 3; ++i) {
        s->position[i] = b->nan ? std::numeric_limits<double>::quiet_NaN() : d.position[i];
        s->velocity[i] = d.velocity[i];
    }
    if (b->absurd == 1) s->position[0] = 2e4;
    if (b->absurd == 2) s->position[1] = 1e300;
    s->buttons = d.buttons;
    s->sequence = ++b->sequence;
    s->timestamp = d.timestampSeconds;
    return 0;
}

inline void bridgeWrite(void* user, const double f[3]) {
    static_cast<Bridge*>(user)->device->write(Eigen::Vector3d(f[0], f[1], f[2]));
}

}  // namespace palp::test
