// The device bridge over loopback: a UdpDevice fed by a UdpBridgeClient drives a Session on the
// AVC phantom (surface y = 0, VC, k 300 N/m). The forces that come back over UDP are the
// snapshots' forces tick for tick (offline lockstep and a 1 kHz live run); a held press feels
// k x depth; a sender that stops gets zero force within the watchdog's timeout; malformed,
// foreign, late and excess datagrams are ignored and counted (10,000 lossy cycles and 5,000
// jittered, reordering ones exactly);
// read() and write() allocate nothing; addresses that do not parse or bind are refused naming the
// address.
#include <gtest/gtest.h>
#include <tbb/task_arena.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <map>
#include <memory>
#include <random>
#include <string>
#include <thread>
#include <vector>

#include "alloc_counter.h"
#include "palp/base/error.h"
#include "palp/haptics/devices/udp_bridge_client.h"
#include "palp/haptics/devices/udp_device.h"
#include "palp/haptics/session.h"
#include "palp/volume/phantom.h"
#include "session_fixtures.h"
#include "udp_fixtures.h"

namespace palp::haptics {
namespace {

using fixtures::kT;
using fixtures::touchX;

using udp_fixtures::address;
using udp_fixtures::kDepth;
using udp_fixtures::kStiffness;
using udp_fixtures::pressState;

class UdpDeviceTest : public udp_fixtures::UdpSceneTest {
  protected:
    static SessionParams params() {
        SessionParams p;
        p.coupling.mode = CouplingMode::VC;
        p.coupling.source = RaySource::VolumeFirstHit;
        p.coupling.baseStiffness = kStiffness;
        p.coupling.maxStiffness = 1400;
        p.proxy.staticFriction = 0;
        p.proxy.dynamicFriction = 0;
        return p;
    }
};

/// Reads @p device until @p done() holds (datagrams on loopback arrive within microseconds;
/// this waits for them without assuming it), at most ~1 s.
template <class Done>
void readUntil(UdpDevice& device, Done done) {
    for (int i = 0; i < 1000 && !done(); ++i) {
        device.read();
        if (!done()) std::this_thread::sleep_for(std::chrono::milliseconds(1));
    }
}

TEST_F(UdpDeviceTest, EndpointsParseAndBadAddressesAreRefusedByName) {
    const UdpEndpoint a = parseUdpEndpoint("127.0.0.1:7405", "--listen");
    EXPECT_EQ(a.host, "127.0.0.1");
    EXPECT_EQ(a.port, 7405);
    const UdpEndpoint b = parseUdpEndpoint("[::1]:0", "--listen");
    EXPECT_EQ(b.host, "::1");
    EXPECT_EQ(b.port, 0);
    for (const char* bad : {"127.0.0.1", "127.0.0.1:", ":7405", "127.0.0.1:65536", "host:7x",
                            "::1:7405", "[::1]7405", "127.0.0.1:-1"}) {
        try {
            parseUdpEndpoint(bad, "--listen");
            ADD_FAILURE() << bad;
        } catch (const ValueError& e) {
            EXPECT_NE(std::string(e.what()).find(std::string("--listen '") + bad + "'"),
                      std::string::npos)
                << e.what();
        }
    }
    UdpDevice first(touchX(), deviceParams());
    UdpDeviceParams same = deviceParams();
    same.listen = address(first);
    try {
        UdpDevice second(touchX(), same);
        ADD_FAILURE() << "bound a port in use";
    } catch (const IoError& e) {
        EXPECT_NE(std::string(e.what()).find(same.listen), std::string::npos) << e.what();
        EXPECT_NE(std::string(e.what()).find("EADDRINUSE"), std::string::npos) << e.what();
    }
    UdpDeviceParams unknown = deviceParams();
    unknown.listen = "300.1.2.3:0";
    EXPECT_THROW(UdpDevice(touchX(), unknown), ValueError);
    UdpDeviceParams foreign = deviceParams();
    foreign.listen = "192.0.2.1:0";  // TEST-NET-1: not an address of this machine
    EXPECT_THROW(UdpDevice(touchX(), foreign), IoError);
    UdpDeviceParams drain = deviceParams();
    drain.maxDrain = 0;
    EXPECT_THROW(UdpDevice(touchX(), drain), ValueError);
}

// Offline lockstep: each tick the client sends the hand's sample, the session steps once, and
// the client receives that tick's force: it equals the snapshot's, bit for bit; the held press
// gives k x depth out of the surface.
TEST_F(UdpDeviceTest, ForcesOverUdpEqualTheSnapshotsAndThePressFeelsKTimesDepth) {
    UdpDevice device(touchX(), deviceParams());
    UdpBridgeClient client(address(device));
    Session session(sScene, device, params());
    // Before any state: stale, no force, nothing sent (nobody to send to), no watchdog trip.
    for (int i = 0; i < 20; ++i) {
        const Snapshot& w = session.step();
        EXPECT_TRUE(w.deviceStale);
        EXPECT_EQ(w.deviceForceScale, 0.0);
        EXPECT_EQ(w.force.norm(), 0.0);
        EXPECT_EQ(w.watchdogTrips, 0u);
    }
    EXPECT_EQ(device.counters().sent, 0u);
    const std::uint64_t ticks = 600;
    Snapshot s;
    int compared = 0;
    for (std::uint64_t i = 0; i < ticks; ++i) {
        ASSERT_TRUE(client.send(pressState(i)));
        s = session.step();
        bridge::ForceMessage f;
        ASSERT_TRUE(client.receive(f, 1.0)) << "tick " << i;
        ASSERT_EQ(f.tick, s.tick);
        EXPECT_EQ(f.force.x(), s.force.x()) << "tick " << i;
        EXPECT_EQ(f.force.y(), s.force.y()) << "tick " << i;
        EXPECT_EQ(f.force.z(), s.force.z()) << "tick " << i;
        EXPECT_EQ(f.forceScale, s.deviceForceScale);
        EXPECT_LE(f.stateSequence, i + 1);
        EXPECT_EQ(f.sequence, i + 1);
        ++compared;
    }
    EXPECT_EQ(compared, 600);
    // Held 3 mm deep: the proxy on the skin iso-surface (within half a voxel of y = 0), the
    // force k x depth pointing out (-y).
    EXPECT_TRUE(s.gateOpen);
    EXPECT_NEAR(s.probe.y(), kDepth, 1e-12);
    EXPECT_NEAR(s.force.y(), -kStiffness * kDepth, kStiffness * 0.5e-3);
    EXPECT_NEAR(s.force.y(), -kStiffness * (s.probe.y() - s.proxy.y()), 1e-9);
    EXPECT_NEAR(s.force.x(), 0, 1e-6);
    readUntil(device, [&] { return device.counters().received == ticks; });
    const UdpDeviceCounters c = device.counters();
    EXPECT_EQ(c.received, ticks);
    EXPECT_EQ(c.lost, 0u);
    EXPECT_EQ(c.late, 0u);
    EXPECT_EQ(c.ignored(), 0u);
    EXPECT_EQ(c.sent, ticks);
    EXPECT_EQ(c.sendFailed, 0u);
}

// The sender stops while pressing: within the watchdog's timeout (10 ms = 10 ticks) the force
// that comes back is zero, flagged stale and cut, and the snapshots say so; it was whole within
// the grace (2 ms).
TEST_F(UdpDeviceTest, SilentSenderGetsZeroForceWithinTheWatchdogTime) {
    UdpDeviceParams dp = deviceParams();
    UdpDevice device(touchX(), dp);
    UdpBridgeClient client(address(device));
    Session session(sScene, device, params());
    const std::uint64_t pressed = 450;
    Snapshot s;
    bridge::ForceMessage f;
    for (std::uint64_t i = 0; i < pressed; ++i) {
        client.send(pressState(i));
        s = session.step();
        ASSERT_TRUE(client.receive(f, 1.0));
    }
    const double held = f.force.norm();
    EXPECT_NEAR(held, kStiffness * kDepth, kStiffness * 0.5e-3);
    const int timeoutTicks = static_cast<int>(std::lround(dp.watchdog.timeoutSeconds / kT));
    const int graceTicks = static_cast<int>(std::lround(dp.watchdog.graceSeconds / kT));
    int firstZero = -1;
    for (int k = 1; k <= 3 * timeoutTicks; ++k) {
        s = session.step();
        ASSERT_TRUE(client.receive(f, 1.0));
        EXPECT_TRUE(f.flags & bridge::kForceStale);
        EXPECT_EQ(f.force, s.force);
        if (k <= graceTicks) {
            EXPECT_NEAR(f.force.norm(), held, 1e-9) << "stale tick " << k;
        }
        if (firstZero < 0 && f.force.norm() == 0) {
            firstZero = k;
            EXPECT_TRUE(f.flags & bridge::kForceCut);
            EXPECT_EQ(f.forceScale, 0.0);
        }
    }
    EXPECT_GT(firstZero, graceTicks);
    // Timeout ticks after the last fresh read (one more should the last sample, sent just before
    // the last pressed step, have reached the socket only after that step's read).
    EXPECT_LE(firstZero, timeoutTicks + 1);
    EXPECT_EQ(s.deviceForceScale, 0.0);
    EXPECT_TRUE(s.deviceStale);
    EXPECT_EQ(s.watchdogTrips, 1u);
}

TEST_F(UdpDeviceTest, MalformedForeignLateAndExcessDatagramsAreIgnoredAndCounted) {
    UdpDeviceParams dp = deviceParams();
    dp.maxDrain = 16;
    UdpDevice device(touchX(), dp);
    UdpBridgeClient client(address(device));
    UdpBridgeClient other(address(device));
    std::array<std::uint8_t, bridge::kStateSize> good{};
    bridge::StateMessage m = pressState(0);
    m.position = {0.01, 0.02, 0.03};
    m.orientation = Eigen::Quaterniond(0.5, 0.5, -0.5, 0.5);
    m.buttons = 3;
    bridge::encode(m, good);
    ASSERT_TRUE(client.sendRaw(good));
    const std::vector<std::uint8_t> g(good.begin(), good.end());
    auto with = [&](std::size_t at, std::uint8_t v) {
        std::vector<std::uint8_t> b = g;
        b[at] = v;
        return b;
    };
    const std::vector<std::uint8_t> shortOne(g.begin(), g.begin() + 5);
    const std::vector<std::uint8_t> truncated(g.begin(), g.end() - 8);
    std::vector<std::uint8_t> oversized = g;
    oversized.resize(1000, 0);  // longer than the receive buffer: its real length is seen
    std::array<std::uint8_t, bridge::kForceSize> force{};
    bridge::encode(bridge::ForceMessage{}, force);
    client.sendRaw(shortOne);
    client.sendRaw(with(0, 'X'));  // magic
    client.sendRaw(with(4, 2));    // version 2
    client.sendRaw(force);         // a force message sent to palp
    client.sendRaw(truncated);
    client.sendRaw(oversized);
    other.sendRaw(with(3, 0));  // a foreign program on another port
    client.sendRaw(good);       // the same sequence again: late
    readUntil(device, [&] {
        const UdpDeviceCounters c = device.counters();
        return c.ignored() + c.received + c.late == 9;
    });
    UdpDeviceCounters c = device.counters();
    EXPECT_EQ(c.received, 1u);
    EXPECT_EQ(c.late, 1u);
    EXPECT_EQ(c.shortDatagrams, 1u);
    EXPECT_EQ(c.badMagic, 2u);
    EXPECT_EQ(c.badVersion, 1u);
    EXPECT_EQ(c.badType, 1u);
    EXPECT_EQ(c.badSize, 2u);
    EXPECT_EQ(c.ignored(), 7u);
    EXPECT_EQ(c.peerChanges, 0u);
    ASSERT_TRUE(device.hasState());
    EXPECT_EQ(device.latestState().position, m.position);
    EXPECT_EQ(device.latestState().buttons, 3u);
    const DeviceState st = device.read();
    EXPECT_EQ(st.position, m.position);
    EXPECT_EQ(st.buttons, 3u);
    // What a viewer thread sees: the same state, orientation included.
    EXPECT_EQ(device.publishedState().sequence, m.sequence);
    EXPECT_EQ(device.publishedState().orientation.coeffs(), m.orientation.coeffs());

    // Sequences 5 then 7: 4 lost; then 6 (late); a burst of 40 beyond maxDrain takes three
    // reads, the newest wins and the rest are superseded.
    for (const std::uint64_t q : {std::uint64_t{5}, std::uint64_t{7}, std::uint64_t{6}}) {
        bridge::StateMessage n = m;
        n.sequence = q;
        client.send(n);
    }
    readUntil(device,
              [&] { return device.counters().received == 3 && device.counters().late == 2; });
    c = device.counters();
    EXPECT_EQ(c.lost, 4u);
    EXPECT_EQ(c.late, 2u);
    EXPECT_EQ(device.latestState().sequence, 7u);
    for (std::uint64_t q = 8; q < 48; ++q) {
        bridge::StateMessage n = m;
        n.sequence = q;
        n.position.x() = static_cast<double>(q);
        client.send(n);
    }
    readUntil(device, [&] { return device.latestState().sequence == 47; });
    c = device.counters();
    EXPECT_EQ(c.received, 3u + 40u);
    EXPECT_EQ(c.lost, 4u);
    EXPECT_GE(c.drainLimited, 1u);
    EXPECT_GE(c.superseded, 20u);
    EXPECT_EQ(device.read().position.x(), 47.0);
    // Another sender takes over (a restarted device program on a new port): counted, accepted.
    bridge::StateMessage o = m;
    o.sequence = 1;
    o.position.x() = -1;
    other.send(o);
    readUntil(device, [&] { return device.counters().peerChanges == 1; });
    EXPECT_EQ(device.latestState().position.x(), -1.0);
    EXPECT_EQ(device.counters().lost, 4u);
    // A sender that falls back by more than kRestartGap restarted: accepted.
    o.sequence = 5000;
    other.send(o);
    o.sequence = 2;
    o.position.x() = -2;
    other.send(o);
    readUntil(device, [&] { return device.counters().restarts == 1; });
    EXPECT_EQ(device.latestState().position.x(), -2.0);
}

// IPv6 loopback, where the machine has it: a state in, a force back to the same address.
TEST_F(UdpDeviceTest, Ipv6LoopbackWorksWhereAvailable) {
    UdpDeviceParams p = deviceParams();
    p.listen = "[::1]:0";
    std::unique_ptr<UdpDevice> device;
    try {
        device = std::make_unique<UdpDevice>(touchX(), p);
    } catch (const IoError& e) {
        GTEST_SKIP() << "no IPv6 loopback here: " << e.what();
    }
    EXPECT_EQ(device->address(), "[::1]:" + std::to_string(device->port()));
    UdpBridgeClient client(device->address());
    bridge::StateMessage m = pressState(3);
    client.send(m);
    readUntil(*device, [&] { return device->hasState(); });
    ASSERT_TRUE(device->hasState());
    EXPECT_EQ(device->latestState().position, m.position);
    device->write(Eigen::Vector3d(0.5, 0, 0));
    bridge::ForceMessage f;
    ASSERT_TRUE(client.receive(f, 1.0));
    EXPECT_EQ(f.force, Eigen::Vector3d(0.5, 0, 0));
    EXPECT_EQ(f.stateSequence, m.sequence);
}

TEST_F(UdpDeviceTest, ReadAndWriteAllocateNothing) {
    UdpDevice device(touchX(), deviceParams());
    UdpBridgeClient client(address(device));
    client.send(pressState(0));
    readUntil(device, [&] { return device.hasState(); });
    const std::vector<std::uint8_t> junk(40, 7);
    std::uint64_t allocations = 0;
    for (std::uint64_t i = 1; i < 500; ++i) {
        client.send(pressState(i));
        if (i % 7 == 0) client.sendRaw(junk);
        const std::uint64_t before = test::threadAllocationCount();
        const DeviceState s = device.read();
        device.write(Eigen::Vector3d(0.1, -0.2, 0.3) + s.position);
        allocations += test::threadAllocationCount() - before;
        bridge::ForceMessage f;
        client.receive(f, 0);
    }
    EXPECT_EQ(allocations, 0u);
    EXPECT_GT(device.counters().sent, 400u);
    EXPECT_GT(device.counters().badMagic, 50u);
}

// 10,000 cycles in lockstep (one State, one tick, one Force) through a scripted lossy network:
// a datagram in 97 never sent (lost), a burst of 5 in a row dropped (longer than the watchdog's
// grace, shorter than its timeout: scaled, never cut), every 211th cycle an old State (3 back)
// delivered again after the current one (late). The counts are exact whatever the delivery's
// timing (sends from one socket arrive in order, or not at all); every tick's Force is that
// tick's snapshot force; the round trip (send -> step -> Force received) is reported.
TEST_F(UdpDeviceTest, TenThousandLossyCyclesAreCountedExactly) {
    UdpDevice device(touchX(), deviceParams());
    UdpBridgeClient client(address(device));
    Session session(sScene, device, params());
    constexpr std::uint64_t kCycles = 10000, kBurst = 5000, kBurstLength = 5;
    const auto dropped = [&](std::uint64_t i) {
        return (i % 97 == 13) || (i >= kBurst && i < kBurst + kBurstLength);
    };
    std::uint64_t sent = 0, lost = 0, late = 0, stale = 0, scaled = 0, matched = 0;
    std::vector<double> roundTripUs;
    roundTripUs.reserve(kCycles);
    for (std::uint64_t i = 0; i < kCycles; ++i) {
        const auto t0 = std::chrono::steady_clock::now();
        if (dropped(i)) {
            ++lost;
        } else {
            ASSERT_TRUE(client.send(pressState(i)));
            ++sent;
            if (i % 211 == 7 && i >= 3) {
                ASSERT_TRUE(client.send(pressState(i - 3)));
                ++late;
            }
        }
        const Snapshot& s = session.step();
        bridge::ForceMessage f;
        ASSERT_TRUE(client.receive(f, 1.0)) << "cycle " << i;
        roundTripUs.push_back(
            std::chrono::duration<double, std::micro>(std::chrono::steady_clock::now() - t0)
                .count());
        ASSERT_EQ(f.tick, s.tick);
        if (f.force == s.force && f.forceScale == s.deviceForceScale) ++matched;
        if (f.flags & bridge::kForceStale) ++stale;
        if (f.forceScale < 1) ++scaled;
        EXPECT_GT(f.forceScale, 0.0) << "cycle " << i;  // no outage reaches the timeout
    }
    readUntil(device, [&] { return device.counters().received == sent; });
    const UdpDeviceCounters c = device.counters();
    EXPECT_EQ(matched, kCycles);
    EXPECT_EQ(c.received, sent);
    EXPECT_EQ(c.lost, lost);
    EXPECT_EQ(c.late, late);
    EXPECT_EQ(c.ignored(), 0u);
    EXPECT_EQ(c.restarts, 0u);
    EXPECT_EQ(c.sent, kCycles);
    EXPECT_EQ(session.latest().watchdogTrips, 0u);
    // Each dropped State leaves its tick stale (or the next one, when a State arrived only
    // after its tick's read); the burst's last 3 ticks are past the 2 ms grace: scaled.
    EXPECT_GE(stale, lost);
    EXPECT_GE(scaled, kBurstLength - 2);
    std::sort(roundTripUs.begin(), roundTripUs.end());
    std::printf(
        "lossy lockstep: %llu cycles, %llu sent, %llu lost, %llu late (counted %llu, %llu, "
        "%llu), %llu stale ticks, %llu scaled; round trip p50 %.1f us, p99 %.1f us\n",
        static_cast<unsigned long long>(kCycles), static_cast<unsigned long long>(sent),
        static_cast<unsigned long long>(lost), static_cast<unsigned long long>(late),
        static_cast<unsigned long long>(c.received), static_cast<unsigned long long>(c.lost),
        static_cast<unsigned long long>(c.late), static_cast<unsigned long long>(stale),
        static_cast<unsigned long long>(scaled), roundTripUs[kCycles / 2],
        roundTripUs[kCycles * 99 / 100]);
}

// A link that delays (issue 38's fault injection): every State reaches palp 0 to 4 ticks after
// it was sent (seeded; the first at once), so some ticks get none and others several, and a
// State delayed longer than a later one arrives after it. Over 5,000 lockstep cycles every
// Force is its tick's snapshot force; the counters are exactly those of the delivery order
// (modelled here: a State newer than all before is received and counts the sequence numbers
// it skipped as lost, an older one is late); no gap between fresh States reaches the watchdog's
// timeout (no cut, no trip) and every force is finite and within the device's maximum.
TEST_F(UdpDeviceTest, JitteredDelaysOfUpToFourTicksAreCountedExactly) {
    UdpDevice device(touchX(), deviceParams());
    UdpBridgeClient client(address(device));
    Session session(sScene, device, params());
    constexpr std::uint64_t kCycles = 5000;
    constexpr int kMaxDelay = 4;
    std::mt19937 rng(38);
    std::uniform_int_distribution<int> delay(0, kMaxDelay);
    std::vector<std::vector<std::uint64_t>> due(kCycles + kMaxDelay + 1);  // sent at cycle c
    for (std::uint64_t i = 0; i < kCycles; ++i)
        due[i + static_cast<std::uint64_t>(i == 0 ? 0 : delay(rng))].push_back(i);
    std::uint64_t newest = 0, received = 0, late = 0, lost = 0;  // the model of the receiver
    std::uint64_t matched = 0, cut = 0, scaled = 0;
    double maxForce = 0, lastWholeY = 0;  // the force of the last fresh, whole tick
    for (std::uint64_t i = 0; i < kCycles; ++i) {
        for (const std::uint64_t j : due[i]) {
            ASSERT_TRUE(client.send(pressState(j)));
            const std::uint64_t sequence = pressState(j).sequence;
            if (sequence <= newest) {
                ++late;
            } else {
                if (newest > 0) lost += sequence - newest - 1;
                newest = sequence;
                ++received;
            }
        }
        const Snapshot& s = session.step();
        bridge::ForceMessage f;
        ASSERT_TRUE(client.receive(f, 1.0)) << "cycle " << i;
        ASSERT_EQ(f.tick, s.tick);
        ASSERT_TRUE(s.force.allFinite()) << "cycle " << i;
        if (f.force == s.force && f.forceScale == s.deviceForceScale) ++matched;
        if (f.forceScale <= 0) ++cut;
        if (f.forceScale < 1) ++scaled;
        maxForce = std::max(maxForce, s.force.norm());
        if (f.forceScale == 1 && !(f.flags & bridge::kForceStale)) lastWholeY = s.force.y();
    }
    readUntil(device, [&] { return device.counters().received == received; });
    const UdpDeviceCounters c = device.counters();
    EXPECT_EQ(matched, kCycles);
    EXPECT_EQ(c.received, received);
    EXPECT_EQ(c.late, late);
    EXPECT_EQ(c.lost, lost);
    EXPECT_EQ(c.restarts, 0u);
    EXPECT_EQ(c.ignored(), 0u);
    EXPECT_GT(late, 100u);  // the script reorders: about a third of the States come late
    EXPECT_EQ(cut, 0u);
    EXPECT_EQ(session.latest().watchdogTrips, 0u);
    EXPECT_LE(maxForce, touchX().maxForceN);
    // The press is held at the end: k x depth, as over a clean link.
    EXPECT_NEAR(lastWholeY, -kStiffness * kDepth, kStiffness * 0.5e-3);
    std::printf(
        "jittered link: %llu cycles, %llu received, %llu late, %llu lost (counted %llu, %llu, "
        "%llu), %llu ticks scaled, none cut\n",
        static_cast<unsigned long long>(kCycles), static_cast<unsigned long long>(received),
        static_cast<unsigned long long>(late), static_cast<unsigned long long>(lost),
        static_cast<unsigned long long>(c.received), static_cast<unsigned long long>(c.late),
        static_cast<unsigned long long>(c.lost), static_cast<unsigned long long>(scaled));
}

// A 1 kHz live run: the session on its servo thread, the remote hand on another thread sending
// every millisecond and taking the forces that come back. Every force received is its tick's
// snapshot force; the sequence bookkeeping adds up; the round trip is reported.
TEST_F(UdpDeviceTest, LiveRunAtOneKilohertzReturnsTheSnapshotsForces) {
    UdpDevice device(touchX(), deviceParams());
    SessionParams sp = params();
    sp.servo.priority = 0;  // no SCHED_FIFO for a test on a shared machine
    sp.traceCapacity = 1u << 12;
    Session session(sScene, device, sp);
    const std::uint64_t samples = 1200;
    std::vector<bridge::ForceMessage> forces;
    forces.reserve(4 * samples);
    std::vector<double> roundTripUs;
    std::atomic<bool> go{false}, done{false};
    std::thread remote([&] {
        UdpBridgeClient client(address(device));
        while (!go.load()) std::this_thread::sleep_for(std::chrono::microseconds(100));
        const auto now = [] {
            return static_cast<std::uint64_t>(
                std::chrono::duration_cast<std::chrono::nanoseconds>(
                    std::chrono::steady_clock::now().time_since_epoch())
                    .count());
        };
        const auto t0 = std::chrono::steady_clock::now();
        for (std::uint64_t i = 0; i < samples; ++i) {
            bridge::StateMessage m = pressState(i);
            m.timeNs = now();
            client.send(m);
            bridge::ForceMessage f;
            while (client.receive(f, 0)) {
                forces.push_back(f);
                if (f.stateTimeNs > 0)
                    roundTripUs.push_back(static_cast<double>(now() - f.stateTimeNs) * 1e-3);
            }
            std::this_thread::sleep_until(t0 + std::chrono::microseconds(1000 * (i + 1)));
        }
        done = true;
    });
    session.start();
    go = true;
    std::map<std::uint64_t, Snapshot> snaps;
    Snapshot s;
    const auto drain = [&] {
        while (session.popTrace(s)) snaps[s.tick] = s;
    };
    while (!done.load()) {
        drain();
        std::this_thread::sleep_for(std::chrono::milliseconds(5));
    }
    remote.join();
    session.stop();
    drain();
    ASSERT_GT(forces.size(), samples / 2);
    int matched = 0;
    const bridge::ForceMessage* lastPressed = nullptr;
    for (const bridge::ForceMessage& f : forces) {
        const auto it = snaps.find(f.tick);
        if (it == snaps.end()) continue;  // a tick the trace ring dropped
        EXPECT_EQ(f.force, it->second.force) << "tick " << f.tick;
        ++matched;
        // A fresh sample at full force: on a loaded machine (ThreadSanitizer on two cores) the
        // remote thread can stall long enough for the watchdog to scale the forces after it down
        // while they climb back (forceScale < 1); those are checked against their tick above.
        if (!(f.flags & bridge::kForceStale) && f.forceScale == 1.0) lastPressed = &f;
    }
    EXPECT_GT(matched, static_cast<int>(samples / 2));
    // The press was felt: the last force computed from a fresh sample (the hold) is k x depth.
    ASSERT_NE(lastPressed, nullptr);
    EXPECT_NEAR(lastPressed->force.y(), -kStiffness * kDepth, kStiffness * 0.5e-3)
        << "tick " << lastPressed->tick << ", state " << lastPressed->stateSequence << " of "
        << samples << ", flags " << lastPressed->flags;
    const UdpDeviceCounters c = device.counters();
    // Every sequence from 1 to the newest accepted is either accepted or counted lost.
    EXPECT_EQ(c.received + c.lost, device.latestState().sequence);
    EXPECT_EQ(c.late, 0u);
    EXPECT_EQ(c.ignored(), 0u);
    std::sort(roundTripUs.begin(), roundTripUs.end());
    if (!roundTripUs.empty()) {
        std::printf(
            "live bridge: %zu forces back, %d matched; round trip p50 %.0f us, p99 %.0f "
            "us; %llu received, %llu superseded, %llu lost\n",
            forces.size(), matched, roundTripUs[roundTripUs.size() / 2],
            roundTripUs[roundTripUs.size() * 99 / 100], static_cast<unsigned long long>(c.received),
            static_cast<unsigned long long>(c.superseded), static_cast<unsigned long long>(c.lost));
    }
}

}  // namespace
}  // namespace palp::haptics
