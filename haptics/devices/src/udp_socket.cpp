#include "udp_socket.h"

#include <netdb.h>
#include <netinet/in.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>
#include <memory>

#include "palp/base/error.h"
#include "palp/base/thread.h"

namespace palp::haptics::detail {

namespace {

struct AddrInfoDeleter {
    void operator()(addrinfo* a) const noexcept { freeaddrinfo(a); }
};
using AddrInfo = std::unique_ptr<addrinfo, AddrInfoDeleter>;

AddrInfo resolve(const UdpEndpoint& e, bool passive, const std::string& what) {
    addrinfo hints{};
    hints.ai_family = AF_UNSPEC;
    hints.ai_socktype = SOCK_DGRAM;
    hints.ai_protocol = IPPROTO_UDP;
    hints.ai_flags = AI_NUMERICSERV | (passive ? AI_PASSIVE : 0);
    addrinfo* found = nullptr;
    const std::string port = std::to_string(e.port);
    const int rc = getaddrinfo(e.host.c_str(), port.c_str(), &hints, &found);
    if (rc != 0 || found == nullptr) {
        throw ValueError(what + ": expected an IP address or a host name that resolves, found '" +
                         e.host + "' (" + gai_strerror(rc) + ")");
    }
    return AddrInfo(found);
}

int openFor(const addrinfo& a, const std::string& what) {
    const int fd =
        ::socket(a.ai_family, a.ai_socktype | SOCK_NONBLOCK | SOCK_CLOEXEC, a.ai_protocol);
    if (fd < 0) throw IoError(what + ": cannot open a UDP socket: " + socketErrorText(errno));
    return fd;
}

}  // namespace

std::string socketErrorText(int err) {
    const char* name = strerrorname_np(err);
    return errorText(err) + " (" + (name ? name : std::to_string(err)) + ")";
}

UdpSocket UdpSocket::bound(const UdpEndpoint& at, const std::string& what) {
    const AddrInfo info = resolve(at, true, what);
    const addrinfo& a = *info;  // the first address the resolver prefers
    UdpSocket s(openFor(a, what));
    if (::bind(s.mFd, a.ai_addr, a.ai_addrlen) != 0) {
        throw IoError(what + ": cannot bind: " + socketErrorText(errno));
    }
    return s;
}

UdpSocket UdpSocket::connected(const UdpEndpoint& to, const std::string& what) {
    const AddrInfo info = resolve(to, false, what);
    const addrinfo& a = *info;
    UdpSocket s(openFor(a, what));
    if (::connect(s.mFd, a.ai_addr, a.ai_addrlen) != 0) {
        throw IoError(what + ": cannot connect: " + socketErrorText(errno));
    }
    return s;
}

UdpSocket::~UdpSocket() {
    if (mFd >= 0) ::close(mFd);
}

UdpSocket& UdpSocket::operator=(UdpSocket&& o) noexcept {
    if (this != &o) {
        if (mFd >= 0) ::close(mFd);
        mFd = o.release();
    }
    return *this;
}

std::uint16_t UdpSocket::localPort() const {
    sockaddr_storage a{};
    socklen_t length = sizeof a;
    if (::getsockname(mFd, reinterpret_cast<sockaddr*>(&a), &length) != 0) {
        throw IoError("udp socket: cannot read its local address: " + socketErrorText(errno));
    }
    if (a.ss_family == AF_INET) return ntohs(reinterpret_cast<const sockaddr_in&>(a).sin_port);
    if (a.ss_family == AF_INET6) return ntohs(reinterpret_cast<const sockaddr_in6&>(a).sin6_port);
    throw IoError("udp socket: expected an IPv4 or IPv6 local address, found family " +
                  std::to_string(a.ss_family));
}

}  // namespace palp::haptics::detail
