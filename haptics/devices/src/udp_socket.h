#pragma once
// A UDP socket owned by one object (set-up only: resolving, binding, connecting), shared by
// UdpDevice and UdpBridgeClient. Errors name the address they were for.

#include <sys/socket.h>

#include <cstdint>
#include <string>

#include "palp/haptics/devices/udp_device.h"

namespace palp::haptics::detail {

class UdpSocket {
  public:
    /// A non-blocking socket bound to @p at. @throw palp::ValueError when @p at does not
    /// resolve; palp::IoError when it cannot be opened or bound (both naming @p what).
    static UdpSocket bound(const UdpEndpoint& at, const std::string& what);
    /// A non-blocking socket connected to @p to (bound to any local port of its family).
    static UdpSocket connected(const UdpEndpoint& to, const std::string& what);

    UdpSocket() = default;
    ~UdpSocket();
    UdpSocket(UdpSocket&& o) noexcept : mFd(o.release()) {}
    UdpSocket& operator=(UdpSocket&& o) noexcept;
    UdpSocket(const UdpSocket&) = delete;
    UdpSocket& operator=(const UdpSocket&) = delete;

    int fd() const noexcept { return mFd; }
    /// The local port (after bind or connect). @throw palp::IoError when unknown.
    std::uint16_t localPort() const;
    /// Gives up ownership.
    int release() noexcept {
        const int fd = mFd;
        mFd = -1;
        return fd;
    }

  private:
    explicit UdpSocket(int fd) : mFd(fd) {}
    int mFd = -1;
};

/// "Address already in use (EADDRINUSE)" for @p err.
std::string socketErrorText(int err);

}  // namespace palp::haptics::detail
