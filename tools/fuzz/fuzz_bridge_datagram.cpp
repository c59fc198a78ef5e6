// libFuzzer: any bytes as a device bridge datagram (docs/device_bridge.md). Decoding never reads
// past the datagram, and a datagram that decodes re-encodes to the same bytes (its reserved
// field aside), for both message types.
#include <cstddef>
#include <cstdint>
#include <cstdlib>
#include <cstring>
#include <span>

#include "palp/haptics/devices/bridge_protocol.h"

namespace bridge = palp::haptics::bridge;

namespace {

/// Equal bytes outside [reservedFrom, reservedFrom + 4).
bool sameOutsideReserved(const std::uint8_t* a, const std::uint8_t* b, std::size_t n,
                         std::size_t reservedFrom) {
    for (std::size_t i = 0; i < n; ++i) {
        if (i >= reservedFrom && i < reservedFrom + 4) continue;
        if (a[i] != b[i]) return false;
    }
    return true;
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
    const std::span<const std::uint8_t> bytes(data, size);
    bridge::StateMessage s;
    if (bridge::decode(bytes, s) == bridge::DecodeStatus::Ok) {
        std::uint8_t again[bridge::kStateSize];
        bridge::encode(s, std::span<std::uint8_t, bridge::kStateSize>(again));
        if (size != bridge::kStateSize || !sameOutsideReserved(data, again, size, 108))
            std::abort();
    }
    bridge::ForceMessage f;
    if (bridge::decode(bytes, f) == bridge::DecodeStatus::Ok) {
        std::uint8_t again[bridge::kForceSize];
        bridge::encode(f, std::span<std::uint8_t, bridge::kForceSize>(again));
        if (size != bridge::kForceSize || !sameOutsideReserved(data, again, size, 84)) std::abort();
    }
    return 0;
}
