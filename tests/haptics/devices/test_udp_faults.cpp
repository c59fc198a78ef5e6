// Bad states over the device bridge reach the remote device as Force flags. A remote hand holds a
// VC press (k 300 N/m, 3 mm deep into the AVC phantom) in lockstep (one State, one tick, one
// Force); then for 30 ticks it sends NaN, a position 20 km or 1e300 m away, a velocity or a jump
// no hand makes, or its last State again (a duplicate: dropped as late, the tick is stale). Each
// Force of those ticks carries the fault's flag from the first faulty tick (or the next, should a
// State reach the socket only after its tick's read), equals its tick's snapshot force, and is
// cut (kForceCut, scale 0) within the 10 ms timeout; once good States return the flags clear
// and the force climbs back to the held one in steps of at most 1/50 of it.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>
#include <memory>
#include <string>

#include "palp/haptics/devices/udp_bridge_client.h"
#include "palp/haptics/devices/udp_device.h"
#include "palp/haptics/session.h"
#include "session_fixtures.h"
#include "udp_fixtures.h"

namespace palp::haptics {
namespace {

using fixtures::kT;
using fixtures::touchX;

using udp_fixtures::kDepth;
using udp_fixtures::kStiffness;
using udp_fixtures::pressState;

class UdpFaultsTest : public udp_fixtures::UdpSceneTest {};

enum class Bad { NaN, Far, Huge, Velocity, Jump, Duplicate };

struct BadCase {
    Bad kind;
    const char* name;
    std::uint32_t flag;   // bridge::ForceFlag the Forces must carry
    std::uint64_t ticks;  // how long it lasts
};

constexpr BadCase kBad[] = {
    {Bad::NaN, "NaN x", bridge::kForceNonFiniteState, 30},
    {Bad::Far, "x 20 km", bridge::kForceOutOfRangeState, 30},
    {Bad::Huge, "y 1e300 m", bridge::kForceOutOfRangeState, 30},
    {Bad::Velocity, "velocity 50 m/s", bridge::kForceTooFastState, 30},
    // 12 ticks: from the 15th on, 10 m/s could have carried a real hand 0.15 m (it is taken).
    {Bad::Jump, "jump 0.15 m", bridge::kForceTooFastState, 12},
    {Bad::Duplicate, "duplicate of the last state", bridge::kForceStale, 30},
};

constexpr std::uint32_t kFaultFlags = bridge::kForceNonFiniteState | bridge::kForceOutOfRangeState |
                                      bridge::kForceTooFastState | bridge::kForceNonFiniteForce |
                                      bridge::kForceJump;

bridge::StateMessage badState(const BadCase& c, std::uint64_t i) {
    bridge::StateMessage m = pressState(i);
    switch (c.kind) {
        case Bad::NaN:
            m.position.x() = std::numeric_limits<double>::quiet_NaN();
            break;
        case Bad::Far:
            m.position.x() = 2e4;
            break;
        case Bad::Huge:
            m.position.y() = 1e300;
            break;
        case Bad::Velocity:
            m.velocity.x() = 50;
            break;
        case Bad::Jump:
            m.position.x() += 0.15;
            break;
        case Bad::Duplicate:
            break;  // sent as the held state below
    }
    return m;
}

TEST_F(UdpFaultsTest, BadStatesAreFlaggedInTheForcesAndCutWithinTheTimeout) {
    constexpr std::uint64_t kPressed = 450;
    for (const BadCase& c : kBad) {
        SCOPED_TRACE(c.name);
        UdpDevice device(touchX(), deviceParams());
        UdpBridgeClient client(udp_fixtures::address(device));
        SessionParams sp;
        sp.coupling.mode = CouplingMode::VC;
        sp.coupling.baseStiffness = kStiffness;
        sp.proxy.staticFriction = 0;
        sp.proxy.dynamicFriction = 0;
        Session session(sScene, device, sp);
        bridge::ForceMessage f;
        Snapshot s;
        for (std::uint64_t i = 0; i < kPressed; ++i) {
            ASSERT_TRUE(client.send(pressState(i)));
            s = session.step();
            ASSERT_TRUE(client.receive(f, 1.0));
        }
        const double held = f.force.norm();
        EXPECT_NEAR(held, kStiffness * kDepth, kStiffness * 0.5e-3);
        int flagged = -1, cut = -1;
        for (std::uint64_t n = 1; n <= c.ticks; ++n) {
            const std::uint64_t i = kPressed - 1 + n;
            ASSERT_TRUE(
                client.send(c.kind == Bad::Duplicate ? pressState(kPressed - 1) : badState(c, i)));
            s = session.step();
            ASSERT_TRUE(client.receive(f, 1.0));
            EXPECT_EQ(f.force, s.force) << n;
            EXPECT_EQ(f.forceScale, s.deviceForceScale) << n;
            EXPECT_TRUE(f.force.allFinite());
            EXPECT_LE(f.force.norm(), held * (1 + 1e-12)) << n;
            if (flagged < 0 && (f.flags & c.flag)) flagged = static_cast<int>(n);
            if (cut < 0 && f.force.norm() == 0) {
                cut = static_cast<int>(n);
                EXPECT_TRUE(f.flags & bridge::kForceCut);
                EXPECT_EQ(f.forceScale, 0.0);
            }
        }
        // The first faulty tick's Force, or the next should its State have come late.
        EXPECT_GE(flagged, 1);
        EXPECT_LE(flagged, 2);
        EXPECT_GE(cut, 3);   // whole through the 2 ms grace
        EXPECT_LE(cut, 11);  // zero by the 10 ms timeout (+1 for a late State)
        std::printf("udp fault %-28s flagged at faulty tick %d, force zero at %d\n", c.name,
                    flagged, cut);
        // Good states again: the flags clear, the force climbs back without a jump.
        double previous = 0, maxStep = 0;
        for (std::uint64_t k = 1; k <= 70; ++k) {
            ASSERT_TRUE(client.send(pressState(kPressed + c.ticks + k)));
            s = session.step();
            ASSERT_TRUE(client.receive(f, 1.0));
            EXPECT_EQ(f.force, s.force);
            if (k > 1) {
                EXPECT_EQ(f.flags & kFaultFlags, 0u) << k;
            }
            maxStep = std::max(maxStep, std::abs(f.force.norm() - previous));
            previous = f.force.norm();
        }
        EXPECT_LE(maxStep, held / 50 * (1 + 1e-6));
        EXPECT_NEAR(previous, held, 1e-9);
        EXPECT_EQ(f.forceScale, 1.0);
        EXPECT_EQ(s.watchdogTrips, 1u);
    }
}

}  // namespace
}  // namespace palp::haptics
