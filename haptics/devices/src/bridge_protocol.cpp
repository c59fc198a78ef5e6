#include "palp/haptics/devices/bridge_protocol.h"

#include <bit>

namespace palp::haptics::bridge {

namespace {

// Every field is written and read byte by byte, least significant first, so the wire format
// does not depend on the host's byte order, struct padding or alignment.

void putU16(std::uint8_t* p, std::uint16_t v) noexcept {
    p[0] = static_cast<std::uint8_t>(v);
    p[1] = static_cast<std::uint8_t>(v >> 8);
}
void putU32(std::uint8_t* p, std::uint32_t v) noexcept {
    for (int i = 0; i < 4; ++i) p[i] = static_cast<std::uint8_t>(v >> (8 * i));
}
void putU64(std::uint8_t* p, std::uint64_t v) noexcept {
    for (int i = 0; i < 8; ++i) p[i] = static_cast<std::uint8_t>(v >> (8 * i));
}
/// IEEE 754 binary64, little-endian.
void putF64(std::uint8_t* p, double v) noexcept { putU64(p, std::bit_cast<std::uint64_t>(v)); }
void putVec(std::uint8_t* p, const Eigen::Vector3d& v) noexcept {
    for (int i = 0; i < 3; ++i) putF64(p + 8 * i, v[i]);
}

std::uint16_t getU16(const std::uint8_t* p) noexcept {
    return static_cast<std::uint16_t>(p[0] | (p[1] << 8));
}
std::uint32_t getU32(const std::uint8_t* p) noexcept {
    std::uint32_t v = 0;
    for (int i = 0; i < 4; ++i) v |= static_cast<std::uint32_t>(p[i]) << (8 * i);
    return v;
}
std::uint64_t getU64(const std::uint8_t* p) noexcept {
    std::uint64_t v = 0;
    for (int i = 0; i < 8; ++i) v |= static_cast<std::uint64_t>(p[i]) << (8 * i);
    return v;
}
double getF64(const std::uint8_t* p) noexcept { return std::bit_cast<double>(getU64(p)); }
Eigen::Vector3d getVec(const std::uint8_t* p) noexcept {
    return {getF64(p), getF64(p + 8), getF64(p + 16)};
}

void putHeader(std::uint8_t* p, MessageType type, std::uint64_t sequence,
               std::uint64_t timeNs) noexcept {
    for (std::size_t i = 0; i < kMagic.size(); ++i) p[i] = kMagic[i];
    putU16(p + 4, kVersion);
    putU16(p + 6, static_cast<std::uint16_t>(type));
    putU64(p + 8, sequence);
    putU64(p + 16, timeNs);
}

/// The checks every decoder runs, in order: length for the fixed fields, magic, version, type,
/// then the type's fixed size.
DecodeStatus checkHeader(std::span<const std::uint8_t> b, MessageType type,
                         std::size_t size) noexcept {
    if (b.size() < 8) return DecodeStatus::Short;
    for (std::size_t i = 0; i < kMagic.size(); ++i)
        if (b[i] != kMagic[i]) return DecodeStatus::BadMagic;
    if (getU16(b.data() + 4) != kVersion) return DecodeStatus::BadVersion;
    if (getU16(b.data() + 6) != static_cast<std::uint16_t>(type)) return DecodeStatus::BadType;
    if (b.size() != size) return DecodeStatus::BadSize;
    return DecodeStatus::Ok;
}

}  // namespace

const char* decodeStatusName(DecodeStatus status) noexcept {
    switch (status) {
        case DecodeStatus::Ok:
            return "ok";
        case DecodeStatus::Short:
            return "short";
        case DecodeStatus::BadMagic:
            return "bad magic";
        case DecodeStatus::BadVersion:
            return "bad version";
        case DecodeStatus::BadType:
            return "bad type";
        case DecodeStatus::BadSize:
            return "bad size";
    }
    return "unknown";
}

void encode(const StateMessage& m, std::span<std::uint8_t, kStateSize> out) noexcept {
    std::uint8_t* p = out.data();
    putHeader(p, MessageType::State, m.sequence, m.timeNs);
    putVec(p + 24, m.position);
    putF64(p + 48, m.orientation.w());
    putF64(p + 56, m.orientation.x());
    putF64(p + 64, m.orientation.y());
    putF64(p + 72, m.orientation.z());
    putVec(p + 80, m.velocity);
    putU32(p + 104, m.buttons);
    putU32(p + 108, 0);  // reserved
}

void encode(const ForceMessage& m, std::span<std::uint8_t, kForceSize> out) noexcept {
    std::uint8_t* p = out.data();
    putHeader(p, MessageType::Force, m.sequence, m.timeNs);
    putVec(p + 24, m.force);
    putU64(p + 48, m.tick);
    putU64(p + 56, m.stateSequence);
    putU64(p + 64, m.stateTimeNs);
    putF64(p + 72, m.forceScale);
    putU32(p + 80, m.flags);
    putU32(p + 84, 0);  // reserved
}

DecodeStatus decode(std::span<const std::uint8_t> bytes, StateMessage& out) noexcept {
    const DecodeStatus s = checkHeader(bytes, MessageType::State, kStateSize);
    if (s != DecodeStatus::Ok) return s;
    const std::uint8_t* p = bytes.data();
    out.sequence = getU64(p + 8);
    out.timeNs = getU64(p + 16);
    out.position = getVec(p + 24);
    out.orientation =
        Eigen::Quaterniond(getF64(p + 48), getF64(p + 56), getF64(p + 64), getF64(p + 72));
    out.velocity = getVec(p + 80);
    out.buttons = getU32(p + 104);
    return s;
}

DecodeStatus decode(std::span<const std::uint8_t> bytes, ForceMessage& out) noexcept {
    const DecodeStatus s = checkHeader(bytes, MessageType::Force, kForceSize);
    if (s != DecodeStatus::Ok) return s;
    const std::uint8_t* p = bytes.data();
    out.sequence = getU64(p + 8);
    out.timeNs = getU64(p + 16);
    out.force = getVec(p + 24);
    out.tick = getU64(p + 48);
    out.stateSequence = getU64(p + 56);
    out.stateTimeNs = getU64(p + 64);
    out.forceScale = getF64(p + 72);
    out.flags = getU32(p + 80);
    return s;
}

}  // namespace palp::haptics::bridge
