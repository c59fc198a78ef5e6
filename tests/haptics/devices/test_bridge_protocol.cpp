// The device bridge's datagrams: the byte layout of docs/device_bridge.md written out by hand
// (little-endian, independent of the host), round trips of both messages bit for bit, and every
// malformed case refused with its reason and without touching the output.

#include <gtest/gtest.h>

#include <array>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <limits>
#include <vector>

#include "palp/haptics/devices/bridge_protocol.h"

namespace palp::haptics::bridge {
namespace {

std::uint64_t readLe(const std::uint8_t* p, int bytes) {
    std::uint64_t v = 0;
    for (int i = 0; i < bytes; ++i) v |= static_cast<std::uint64_t>(p[i]) << (8 * i);
    return v;
}

double readF64(const std::uint8_t* p) {
    const std::uint64_t bits = readLe(p, 8);
    double d;
    std::memcpy(&d, &bits, 8);  // the test's own reading: bits of IEEE 754 binary64
    return d;
}

StateMessage sampleState() {
    StateMessage m;
    m.sequence = 0x0102030405060708ull;
    m.timeNs = 1234567890123456789ull;
    m.position = {0.0125, -0.25, 3e-5};
    m.orientation = Eigen::Quaterniond(0.5, -0.5, 0.5, 0.5);
    m.velocity = {-1.5, 0.0, 1e-9};
    m.buttons = 0x80000005u;
    return m;
}

ForceMessage sampleForce() {
    ForceMessage m;
    m.sequence = 42;
    m.timeNs = 987654321;
    m.force = {0.1, -2.75, 1.0 / 3.0};
    m.tick = 0xfedcba9876543210ull;
    m.stateSequence = 41;
    m.stateTimeNs = 123;
    m.forceScale = 0.375;
    m.flags = kForceStale | kForceScaled;
    return m;
}

std::array<std::uint8_t, kStateSize> encoded(const StateMessage& m) {
    std::array<std::uint8_t, kStateSize> b{};
    encode(m, b);
    return b;
}

std::array<std::uint8_t, kForceSize> encoded(const ForceMessage& m) {
    std::array<std::uint8_t, kForceSize> b{};
    encode(m, b);
    return b;
}

TEST(BridgeProtocol, StateLayoutIsLittleEndianAtTheDocumentedOffsets) {
    const StateMessage m = sampleState();
    const auto b = encoded(m);
    EXPECT_EQ(std::string(reinterpret_cast<const char*>(b.data()), 4), "PLPB");
    EXPECT_EQ(b[4], 1);  // version 1, low byte first
    EXPECT_EQ(b[5], 0);
    EXPECT_EQ(readLe(&b[6], 2), 1u);  // State
    // Sequence 0x0102030405060708: least significant byte first.
    for (std::size_t i = 0; i < 8; ++i) EXPECT_EQ(b[8 + i], 8 - i);
    EXPECT_EQ(readLe(&b[16], 8), m.timeNs);
    for (int i = 0; i < 3; ++i) EXPECT_EQ(readF64(b.data() + 24 + 8 * i), m.position[i]);
    EXPECT_EQ(readF64(&b[48]), 0.5);  // w first
    EXPECT_EQ(readF64(&b[56]), -0.5);
    for (int i = 0; i < 3; ++i) EXPECT_EQ(readF64(b.data() + 80 + 8 * i), m.velocity[i]);
    EXPECT_EQ(readLe(&b[104], 4), m.buttons);
    EXPECT_EQ(readLe(&b[108], 4), 0u);  // reserved
    // 1.0 as a double is 0x3ff0000000000000: its top byte comes last.
    StateMessage one;
    one.position = {1, 0, 0};
    const auto c = encoded(one);
    EXPECT_EQ(c[31], 0x3f);
    EXPECT_EQ(c[30], 0xf0);
    for (std::size_t i = 24; i < 30; ++i) EXPECT_EQ(c[i], 0);
}

TEST(BridgeProtocol, ForceLayoutIsLittleEndianAtTheDocumentedOffsets) {
    const ForceMessage m = sampleForce();
    const auto b = encoded(m);
    EXPECT_EQ(std::string(reinterpret_cast<const char*>(b.data()), 4), "PLPB");
    EXPECT_EQ(readLe(&b[4], 2), 1u);
    EXPECT_EQ(readLe(&b[6], 2), 2u);  // Force
    EXPECT_EQ(readLe(&b[8], 8), 42u);
    EXPECT_EQ(readLe(&b[16], 8), 987654321u);
    for (int i = 0; i < 3; ++i) EXPECT_EQ(readF64(b.data() + 24 + 8 * i), m.force[i]);
    EXPECT_EQ(b[48], 0x10);  // tick, low byte first
    EXPECT_EQ(b[55], 0xfe);
    EXPECT_EQ(readLe(&b[56], 8), 41u);
    EXPECT_EQ(readLe(&b[64], 8), 123u);
    EXPECT_EQ(readF64(&b[72]), 0.375);
    EXPECT_EQ(readLe(&b[80], 4), 3u);
    EXPECT_EQ(readLe(&b[84], 4), 0u);
}

TEST(BridgeProtocol, RoundTripsKeepEveryBit) {
    const StateMessage s = sampleState();
    StateMessage sd;
    ASSERT_EQ(decode(encoded(s), sd), DecodeStatus::Ok);
    EXPECT_EQ(sd.sequence, s.sequence);
    EXPECT_EQ(sd.timeNs, s.timeNs);
    EXPECT_EQ(sd.position, s.position);
    EXPECT_EQ(sd.orientation.coeffs(), s.orientation.coeffs());
    EXPECT_EQ(sd.velocity, s.velocity);
    EXPECT_EQ(sd.buttons, s.buttons);

    const ForceMessage f = sampleForce();
    ForceMessage fd;
    ASSERT_EQ(decode(encoded(f), fd), DecodeStatus::Ok);
    EXPECT_EQ(fd.sequence, f.sequence);
    EXPECT_EQ(fd.timeNs, f.timeNs);
    EXPECT_EQ(fd.force, f.force);
    EXPECT_EQ(fd.tick, f.tick);
    EXPECT_EQ(fd.stateSequence, f.stateSequence);
    EXPECT_EQ(fd.stateTimeNs, f.stateTimeNs);
    EXPECT_EQ(fd.forceScale, f.forceScale);
    EXPECT_EQ(fd.flags, f.flags);

    // Extremes: the largest counters, signed zero, denormals, infinities and NaN pass as sent.
    StateMessage x;
    x.sequence = std::numeric_limits<std::uint64_t>::max();
    x.timeNs = std::numeric_limits<std::uint64_t>::max();
    x.position = {-0.0, std::numeric_limits<double>::denorm_min(),
                  -std::numeric_limits<double>::infinity()};
    x.velocity = {std::numeric_limits<double>::quiet_NaN(), std::numeric_limits<double>::max(),
                  std::numeric_limits<double>::lowest()};
    StateMessage xd;
    ASSERT_EQ(decode(encoded(x), xd), DecodeStatus::Ok);
    EXPECT_EQ(xd.sequence, x.sequence);
    EXPECT_EQ(xd.timeNs, x.timeNs);
    EXPECT_TRUE(std::signbit(xd.position.x()));
    EXPECT_EQ(xd.position.y(), x.position.y());
    EXPECT_EQ(xd.position.z(), x.position.z());
    EXPECT_TRUE(std::isnan(xd.velocity.x()));
    EXPECT_EQ(xd.velocity.y(), x.velocity.y());
    EXPECT_EQ(xd.velocity.z(), x.velocity.z());
}

/// Decodes @p bytes as a state into a message preset to a marker, checks the status and that a
/// refused datagram left the message untouched.
void expectRefused(const std::vector<std::uint8_t>& bytes, DecodeStatus want) {
    StateMessage out;
    out.sequence = 777;
    EXPECT_EQ(decode(bytes, out), want) << decodeStatusName(want);
    EXPECT_EQ(out.sequence, 777u);
}

TEST(BridgeProtocol, MalformedDatagramsAreRefusedWithTheirReason) {
    const auto good = encoded(sampleState());
    const std::vector<std::uint8_t> g(good.begin(), good.end());

    expectRefused({}, DecodeStatus::Short);
    expectRefused(std::vector<std::uint8_t>(g.begin(), g.begin() + 7), DecodeStatus::Short);
    // 8 bytes: magic, version and type readable, the rest missing.
    expectRefused(std::vector<std::uint8_t>(g.begin(), g.begin() + 8), DecodeStatus::BadSize);
    expectRefused(std::vector<std::uint8_t>(g.begin(), g.end() - 1), DecodeStatus::BadSize);
    std::vector<std::uint8_t> longer = g;
    longer.push_back(0);
    expectRefused(longer, DecodeStatus::BadSize);

    for (int i = 0; i < 4; ++i) {
        std::vector<std::uint8_t> bad = g;
        bad[static_cast<std::size_t>(i)] ^= 0x20;  // "pLPB", ...
        expectRefused(bad, DecodeStatus::BadMagic);
    }
    // A foreign datagram of the same length (e.g. another program on the port).
    expectRefused(std::vector<std::uint8_t>(kStateSize, 0xAB), DecodeStatus::BadMagic);
    // Big-endian sender: version 1 written as 00 01 reads as 256.
    std::vector<std::uint8_t> be = g;
    be[4] = 0;
    be[5] = 1;
    expectRefused(be, DecodeStatus::BadVersion);
    for (const unsigned v : {0u, 2u, 0xffffu}) {
        std::vector<std::uint8_t> bad = g;
        bad[4] = static_cast<std::uint8_t>(v);
        bad[5] = static_cast<std::uint8_t>(v >> 8);
        expectRefused(bad, DecodeStatus::BadVersion);
    }
    // A future version is refused before its size is judged (its layout may differ).
    std::vector<std::uint8_t> future(g.begin(), g.begin() + 40);
    future[4] = 2;
    expectRefused(future, DecodeStatus::BadVersion);
    for (const unsigned t : {0u, 2u, 3u, 0x100u}) {
        std::vector<std::uint8_t> bad = g;
        bad[6] = static_cast<std::uint8_t>(t);
        bad[7] = static_cast<std::uint8_t>(t >> 8);
        expectRefused(bad, DecodeStatus::BadType);
    }
    // A force message offered to the state decoder and the other way round.
    const auto f = encoded(sampleForce());
    expectRefused(std::vector<std::uint8_t>(f.begin(), f.end()), DecodeStatus::BadType);
    ForceMessage fo;
    fo.tick = 5;
    EXPECT_EQ(decode(g, fo), DecodeStatus::BadType);
    EXPECT_EQ(decode(std::vector<std::uint8_t>(f.begin(), f.end() - 8), fo), DecodeStatus::BadSize);
    EXPECT_EQ(fo.tick, 5u);
    EXPECT_STREQ(decodeStatusName(DecodeStatus::BadMagic), "bad magic");
}

}  // namespace
}  // namespace palp::haptics::bridge
