#include "palp/haptics/devices/udp_bridge_client.h"

#include <poll.h>
#include <sys/socket.h>
#include <unistd.h>

#include <cerrno>
#include <chrono>
#include <cmath>
#include <string>

#include "palp/haptics/devices/udp_device.h"
#include "udp_socket.h"

namespace palp::haptics {

UdpBridgeClient::UdpBridgeClient(std::string_view server) {
    const UdpEndpoint to = parseUdpEndpoint(server, "bridge server address");
    detail::UdpSocket s =
        detail::UdpSocket::connected(to, "bridge server address " + std::string(server));
    mPort = s.localPort();
    mSocket = s.release();
}

UdpBridgeClient::~UdpBridgeClient() {
    if (mSocket >= 0) ::close(mSocket);
}

bool UdpBridgeClient::send(const bridge::StateMessage& m) noexcept {
    std::uint8_t buffer[bridge::kStateSize];
    bridge::encode(m, std::span<std::uint8_t, bridge::kStateSize>(buffer));
    return sendRaw(buffer);
}

bool UdpBridgeClient::sendRaw(std::span<const std::uint8_t> bytes) noexcept {
    const ssize_t n = ::send(mSocket, bytes.data(), bytes.size(), MSG_DONTWAIT | MSG_NOSIGNAL);
    return n == static_cast<ssize_t>(bytes.size());
}

bool UdpBridgeClient::receive(bridge::ForceMessage& out, double timeoutSeconds) noexcept {
    using Clock = std::chrono::steady_clock;
    const auto deadline =
        Clock::now() + std::chrono::duration_cast<Clock::duration>(
                           std::chrono::duration<double>(std::max(0.0, timeoutSeconds)));
    std::uint8_t buffer[bridge::kMaxDatagram];
    for (;;) {
        const ssize_t n = ::recv(mSocket, buffer, sizeof buffer, MSG_DONTWAIT | MSG_TRUNC);
        if (n >= 0) {
            const auto length = std::min(static_cast<std::size_t>(n), sizeof buffer);
            if (bridge::decode(std::span<const std::uint8_t>(buffer, length), out) ==
                bridge::DecodeStatus::Ok)
                return true;
            ++mIgnored;
            continue;
        }
        // Nothing queued (or an ICMP error from a send to a closed port): wait for more.
        const auto left = std::chrono::duration<double>(deadline - Clock::now()).count();
        if (left <= 0) return false;
        pollfd p{mSocket, POLLIN, 0};
        ::poll(&p, 1, static_cast<int>(std::ceil(left * 1e3)));
    }
}

}  // namespace palp::haptics
