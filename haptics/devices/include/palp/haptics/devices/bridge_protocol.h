#pragma once
/// @file
/// The device bridge's UDP protocol (docs/device_bridge.md): fixed-size little-endian datagrams
/// that carry a remote device's state to palp (StateMessage) and palp's force back
/// (ForceMessage), with explicit byte-by-byte encoding and decoding (no struct layout assumed).

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <array>
#include <cstddef>
#include <cstdint>
#include <span>

namespace palp::haptics::bridge {

/// The first four bytes of every datagram: ASCII "PLPB".
inline constexpr std::array<std::uint8_t, 4> kMagic{'P', 'L', 'P', 'B'};
/// The protocol version this code speaks (bytes 4-5).
inline constexpr std::uint16_t kVersion = 1;

/// Bytes 6-7 of every datagram.
enum class MessageType : std::uint16_t {
    State = 1,  ///< remote device -> palp
    Force = 2,  ///< palp -> remote device
};

/// Header: magic, version, type, sequence, time.
inline constexpr std::size_t kHeaderSize = 24;
/// A whole StateMessage datagram.
inline constexpr std::size_t kStateSize = 112;
/// A whole ForceMessage datagram.
inline constexpr std::size_t kForceSize = 88;
/// Big enough for any datagram of this version plus one byte (so a long one is seen as long).
inline constexpr std::size_t kMaxDatagram = 128;

/// Bits of ForceMessage::flags.
enum ForceFlag : std::uint32_t {
    kForceStale = 1u << 0,    ///< no fresh, good state reached palp for this tick (watchdog)
    kForceScaled = 1u << 1,   ///< a fault ramp scaled the force below 1 (forceScale < 1)
    kForceCut = 1u << 2,      ///< a fault ramp cut the force to zero (forceScale 0)
    kForceClamped = 1u << 3,  ///< the device clamped the force to forceScale x maxForceN
    /// This tick's state was refused (its force is the last good one, then ramped to zero):
    kForceNonFiniteState = 1u << 4,   ///< a NaN or infinite position, velocity or time
    kForceOutOfRangeState = 1u << 5,  ///< a position outside the device's workspace (+ margin)
    kForceTooFastState = 1u << 6,     ///< a speed or a jump since the last good state no hand makes
    kForceNonFiniteForce = 1u << 7,   ///< palp's force was not finite (the last good one held)
    kForceJump = 1u << 8,             ///< palp's force would have jumped (limited to a step)
    kForceOverload = 1u << 9,  ///< palp's servo loop overran its budget: no force until restarted
    /// palp's servo loop shed work to keep its deadlines (VC coupling, tissue frozen): the force
    /// is still rendered, with less detail.
    kForceShed = 1u << 10,
};

/// Remote device -> palp: one sample of the device, in the device frame.
struct StateMessage {
    std::uint64_t sequence = 0;  ///< sender's count, +1 per datagram
    std::uint64_t timeNs = 0;    ///< sender's clock at the sample, ns (any epoch, monotonic)
    Eigen::Vector3d position{Eigen::Vector3d::Zero()};  ///< m
    /// End-effector orientation (w, x, y, z on the wire); identity when the device has none.
    Eigen::Quaterniond orientation{Eigen::Quaterniond::Identity()};
    Eigen::Vector3d velocity{Eigen::Vector3d::Zero()};  ///< m/s
    std::uint32_t buttons = 0;                          ///< bit i: button i pressed
};

/// palp -> remote device: the force of one servo tick.
struct ForceMessage {
    std::uint64_t sequence = 0;  ///< palp's count of force datagrams sent to this peer
    std::uint64_t timeNs = 0;    ///< palp's CLOCK_MONOTONIC at sending, ns
    Eigen::Vector3d force{Eigen::Vector3d::Zero()};  ///< N, device frame
    std::uint64_t tick = 0;                          ///< the session's tick (Snapshot::tick)
    /// The newest state this force was computed from (0 / 0 when none): its sequence and the
    /// sender's timeNs echoed, so the remote side measures the round trip on its own clock.
    std::uint64_t stateSequence = 0;
    std::uint64_t stateTimeNs = 0;
    /// The factor (0..1) applied to this force: the watchdog's and the session's fault ramp
    /// (the smaller).
    double forceScale = 1;
    std::uint32_t flags = 0;  ///< ForceFlag bits
};

/// Why a datagram was refused, in the order the checks run.
enum class DecodeStatus : std::uint8_t {
    Ok,
    Short,       ///< fewer than 8 bytes: no magic, version and type to read
    BadMagic,    ///< bytes 0-3 are not kMagic (a foreign datagram)
    BadVersion,  ///< a version other than kVersion
    BadType,     ///< not the message type the decoder expects
    BadSize,     ///< the right type but not its fixed size (truncated or padded)
};

/// "ok", "short", "bad magic", ...
const char* decodeStatusName(DecodeStatus status) noexcept;

/// Writes @p m into @p out (kStateSize bytes). @par Real-time noexcept, allocation-free.
void encode(const StateMessage& m, std::span<std::uint8_t, kStateSize> out) noexcept;
/// Writes @p m into @p out (kForceSize bytes). @par Real-time noexcept, allocation-free.
void encode(const ForceMessage& m, std::span<std::uint8_t, kForceSize> out) noexcept;

/// Reads a StateMessage from @p bytes (the whole datagram); @p out is written only on Ok.
/// Values are taken as sent (a non-finite position is the receiver's to judge).
/// @par Real-time noexcept, allocation-free.
DecodeStatus decode(std::span<const std::uint8_t> bytes, StateMessage& out) noexcept;
/// Reads a ForceMessage from @p bytes; @p out is written only on Ok.
DecodeStatus decode(std::span<const std::uint8_t> bytes, ForceMessage& out) noexcept;

}  // namespace palp::haptics::bridge
