#pragma once
/// @file
/// The remote side of the device bridge: sends StateMessages to a UdpDevice and receives its
/// ForceMessages. Used by `palp bridge-sim`, the tests, and as the reference for a device
/// program in another language (docs/device_bridge.md).

#include <cstdint>
#include <span>
#include <string_view>

#include "palp/haptics/devices/bridge_protocol.h"

namespace palp::haptics {

/// A UDP socket connected to a UdpDevice's address.
///
/// @par Threading  One thread at a time; not for a servo thread (receive() may wait).
class UdpBridgeClient {
  public:
    /// @param server "host:port" of the UdpDevice
    /// @throw palp::ValueError for an address that does not parse or resolve; palp::IoError
    ///        when the socket cannot be opened or connected (naming the address).
    explicit UdpBridgeClient(std::string_view server);
    ~UdpBridgeClient();
    UdpBridgeClient(const UdpBridgeClient&) = delete;
    UdpBridgeClient& operator=(const UdpBridgeClient&) = delete;

    /// Sends @p m without waiting; false when the socket refused it (full, or ICMP "port
    /// unreachable" from an earlier datagram: nobody listens yet).
    bool send(const bridge::StateMessage& m) noexcept;
    /// Sends any bytes (malformed datagrams in tests); false when refused.
    bool sendRaw(std::span<const std::uint8_t> bytes) noexcept;
    /// Waits up to @p timeoutSeconds for a ForceMessage (0: only what is queued); datagrams
    /// that do not decode as one are skipped and counted (ignored()). False on timeout.
    bool receive(bridge::ForceMessage& out, double timeoutSeconds) noexcept;

    /// Datagrams receive() skipped.
    std::uint64_t ignored() const noexcept { return mIgnored; }
    /// The local port the client sends from.
    std::uint16_t localPort() const noexcept { return mPort; }

  private:
    int mSocket = -1;
    std::uint16_t mPort = 0;
    std::uint64_t mIgnored = 0;
};

}  // namespace palp::haptics
