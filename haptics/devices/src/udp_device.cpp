#include "palp/haptics/devices/udp_device.h"

#include <arpa/inet.h>
#include <netdb.h>
#include <netinet/in.h>
#include <sys/socket.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <charconv>
#include <cstring>
#include <ctime>
#include <span>

#include "palp/base/error.h"
#include "palp/base/thread.h"
#include "palp/base/validate.h"
#include "palp/haptics/rendering/safety.h"
#include "udp_socket.h"

namespace palp::haptics {

namespace {

std::uint64_t monotonicNs() noexcept {
    timespec ts{};
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return static_cast<std::uint64_t>(ts.tv_sec) * 1000000000ull +
           static_cast<std::uint64_t>(ts.tv_nsec);
}

bool sameAddress(const sockaddr_storage& a, socklen_t al, const sockaddr_storage& b,
                 socklen_t bl) noexcept {
    if (a.ss_family != b.ss_family || al != bl) return false;
    if (a.ss_family == AF_INET) {
        const auto& x = reinterpret_cast<const sockaddr_in&>(a);
        const auto& y = reinterpret_cast<const sockaddr_in&>(b);
        return x.sin_port == y.sin_port && x.sin_addr.s_addr == y.sin_addr.s_addr;
    }
    if (a.ss_family == AF_INET6) {
        const auto& x = reinterpret_cast<const sockaddr_in6&>(a);
        const auto& y = reinterpret_cast<const sockaddr_in6&>(b);
        return x.sin6_port == y.sin6_port &&
               std::memcmp(&x.sin6_addr, &y.sin6_addr, sizeof x.sin6_addr) == 0;
    }
    return std::memcmp(&a, &b, al) == 0;
}

}  // namespace

UdpEndpoint parseUdpEndpoint(std::string_view text, std::string_view what) {
    const auto refuse = [&](const std::string& why) {
        throw ValueError(std::string(what) + " '" + std::string(text) +
                         "': expected host:port (e.g. 127.0.0.1:7405 or [::1]:7405), " + why);
    };
    UdpEndpoint e;
    std::string_view portText;
    if (!text.empty() && text.front() == '[') {
        const std::size_t close = text.find(']');
        if (close == std::string_view::npos || close + 1 >= text.size() || text[close + 1] != ':')
            refuse("found no ']:' after the IPv6 address");
        e.host = std::string(text.substr(1, close - 1));
        portText = text.substr(close + 2);
    } else {
        const std::size_t colon = text.rfind(':');
        if (colon == std::string_view::npos) refuse("found no ':port'");
        if (text.find(':') != colon) refuse("found several ':' (write an IPv6 address in [])");
        e.host = std::string(text.substr(0, colon));
        portText = text.substr(colon + 1);
    }
    if (e.host.empty()) refuse("found no host");
    unsigned port = 0;
    const auto [end, ec] =
        std::from_chars(portText.data(), portText.data() + portText.size(), port);
    if (portText.empty() || ec != std::errc() || end != portText.data() + portText.size() ||
        port > 65535)
        refuse("found port '" + std::string(portText) + "' (expected 0..65535)");
    e.port = static_cast<std::uint16_t>(port);
    return e;
}

void validateUdpDeviceParams(const UdpDeviceParams& params) {
    validateWatchdogParams(params.watchdog);
    requireInRange("udp device maxDrain", params.maxDrain, 1, 4096);
    requireInRange("udp device receiveBufferBytes", params.receiveBufferBytes, 0, 1 << 26, "bytes");
}

UdpDevice::UdpDevice(const DeviceSpec& spec, const UdpDeviceParams& params)
    : mSpec(spec),
      mParams(params),
      mWatchdog((validateUdpDeviceParams(params), mLink), params.watchdog, params.periodSeconds) {
    const UdpEndpoint at = parseUdpEndpoint(params.listen, "udp device listen address");
    detail::UdpSocket s =
        detail::UdpSocket::bound(at, "udp device listen address " + params.listen);
    if (params.receiveBufferBytes > 0) {
        const int size = params.receiveBufferBytes;
        setsockopt(s.fd(), SOL_SOCKET, SO_RCVBUF, &size, sizeof size);  // a hint: not checked
    }
    mPort = s.localPort();
    mAddress = (at.host.find(':') != std::string::npos ? "[" + at.host + "]" : at.host) + ":" +
               std::to_string(mPort);
    mSocket = s.release();
}

UdpDevice::~UdpDevice() {
    if (mSocket >= 0) ::close(mSocket);
}

UdpDeviceCounters UdpDevice::counters() const noexcept {
    const auto get = [](const std::atomic<std::uint64_t>& a) {
        return a.load(std::memory_order_relaxed);
    };
    const AtomicCounters& c = mCounts;
    UdpDeviceCounters r;
    r.received = get(c.received);
    r.superseded = get(c.superseded);
    r.lost = get(c.lost);
    r.late = get(c.late);
    r.restarts = get(c.restarts);
    r.peerChanges = get(c.peerChanges);
    r.shortDatagrams = get(c.shortDatagrams);
    r.badMagic = get(c.badMagic);
    r.badVersion = get(c.badVersion);
    r.badType = get(c.badType);
    r.badSize = get(c.badSize);
    r.receiveErrors = get(c.receiveErrors);
    r.drainLimited = get(c.drainLimited);
    r.sent = get(c.sent);
    r.sendFailed = get(c.sendFailed);
    return r;
}

namespace {
/// One writer (the servo thread): a relaxed load and store, no read-modify-write needed.
void bump(std::atomic<std::uint64_t>& a, std::uint64_t by = 1) noexcept {
    a.store(a.load(std::memory_order_relaxed) + by, std::memory_order_relaxed);
}
}  // namespace

void UdpDevice::accept(const bridge::StateMessage& m, const sockaddr_storage& from,
                       socklen_t fromLength) noexcept {
    AtomicCounters& c = mCounts;
    if (!mHasState || !sameAddress(from, fromLength, mPeer, mPeerLength)) {
        if (mHasState) bump(c.peerChanges);
        mPeer = from;
        mPeerLength = fromLength;
    } else if (m.sequence <= mState.sequence) {
        if (mState.sequence - m.sequence <= kRestartGap) {
            bump(c.late);
            return;
        }
        bump(c.restarts);
    } else {
        bump(c.lost, m.sequence - mState.sequence - 1);
    }
    mState = m;
    mHasState = true;
    bump(c.received);
}

void UdpDevice::drain() noexcept {
    AtomicCounters& c = mCounts;
    std::uint8_t buffer[bridge::kMaxDatagram];
    bool acceptedThisRead = false;
    int i = 0;
    for (; i < mParams.maxDrain; ++i) {
        sockaddr_storage from{};
        socklen_t fromLength = sizeof from;
        // MSG_TRUNC: the datagram's real length, so an oversized one is seen as such.
        const ssize_t n = ::recvfrom(mSocket, buffer, sizeof buffer, MSG_DONTWAIT | MSG_TRUNC,
                                     reinterpret_cast<sockaddr*>(&from), &fromLength);
        if (n < 0) {
            if (errno != EAGAIN && errno != EWOULDBLOCK && errno != EINTR) bump(c.receiveErrors);
            break;
        }
        const std::size_t length = static_cast<std::size_t>(n);
        // A datagram longer than the buffer is decoded from what fits: still not a state's size.
        const std::span<const std::uint8_t> bytes(buffer, std::min(length, sizeof buffer));
        bridge::StateMessage m;
        switch (bridge::decode(bytes, m)) {
            case bridge::DecodeStatus::Ok: {
                const std::uint64_t before = c.received.load(std::memory_order_relaxed);
                accept(m, from, fromLength);
                if (c.received.load(std::memory_order_relaxed) != before) {
                    if (acceptedThisRead) bump(c.superseded);
                    acceptedThisRead = true;
                }
                break;
            }
            case bridge::DecodeStatus::Short:
                bump(c.shortDatagrams);
                break;
            case bridge::DecodeStatus::BadMagic:
                bump(c.badMagic);
                break;
            case bridge::DecodeStatus::BadVersion:
                bump(c.badVersion);
                break;
            case bridge::DecodeStatus::BadType:
                bump(c.badType);
                break;
            case bridge::DecodeStatus::BadSize:
                bump(c.badSize);
                break;
        }
    }
    if (i == mParams.maxDrain) bump(c.drainLimited);
    if (acceptedThisRead) {
        mDeviceState.position = mState.position;
        mDeviceState.velocity = mState.velocity;
        mDeviceState.buttons = mState.buttons;
        mDeviceState.timestampSeconds = static_cast<double>(mState.timeNs) * 1e-9;
        mDeviceState.sequence = mState.sequence;
        mPublished.back().value = mState;
        mPublished.publish();
    }
}

DeviceState UdpDevice::Link::read() noexcept {
    mOwner.drain();
    return mOwner.mDeviceState;
}

DeviceState UdpDevice::read() noexcept {
    if (!mHasState) {
        // Before the first state there is no sample for the watchdog to judge: the device rests
        // at the origin and health() asks for no force.
        drain();
        if (!mHasState) {
            ++mWaitingReads;
            return mDeviceState;
        }
    }
    return mWatchdog.read();
}

DeviceHealth UdpDevice::health() const noexcept {
    if (mHasState) return mWatchdog.health();
    DeviceHealth h;
    h.stale = true;
    h.forceScale = 0;
    h.staleTicks = mWaitingReads;
    h.faults = kFaultStale;
    return h;
}

void UdpDevice::reportFaults(std::uint32_t faults, double forceScale) noexcept {
    mReported = true;
    mReportedFaults = faults;
    mReportedScale = forceScale;
}

namespace {
/// ForceFlag bits of DeviceFault bits (kFaultStale travels as kForceStale from health()).
std::uint32_t forceFlags(std::uint32_t faults) noexcept {
    std::uint32_t f = 0;
    if (faults & kFaultNonFinite) f |= bridge::kForceNonFiniteState;
    if (faults & kFaultOutOfRange) f |= bridge::kForceOutOfRangeState;
    if (faults & kFaultTooFast) f |= bridge::kForceTooFastState;
    if (faults & kFaultForceNonFinite) f |= bridge::kForceNonFiniteForce;
    if (faults & kFaultForceJump) f |= bridge::kForceJump;
    if (faults & kFaultOverload) f |= bridge::kForceOverload;
    if (faults & kFaultShed) f |= bridge::kForceShed;
    return f;
}
}  // namespace

void UdpDevice::write(const Eigen::Vector3d& forceN) noexcept {
    const std::uint64_t tick = mWrites++;
    const bool reported = mReported;
    mReported = false;
    if (!mHasState) return;
    DeviceHealth h = mWatchdog.health();
    if (reported) {
        h.forceScale = std::min(h.forceScale, mReportedScale);
        h.faults |= mReportedFaults;
    }
    bridge::ForceMessage m;
    m.flags = forceFlags(h.faults);
    const double limit = h.forceScale * mSpec.maxForceN;
    m.force = clampForce(forceN, limit);
    m.sequence = ++mSendSequence;
    m.timeNs = monotonicNs();
    m.tick = tick;
    m.stateSequence = mState.sequence;
    m.stateTimeNs = mState.timeNs;
    m.forceScale = h.forceScale;
    if (h.stale) m.flags |= bridge::kForceStale;
    if (h.forceScale < 1) m.flags |= bridge::kForceScaled;
    if (h.forceScale <= 0) m.flags |= bridge::kForceCut;
    if (forceN.norm() > limit && limit > 0) m.flags |= bridge::kForceClamped;
    std::uint8_t buffer[bridge::kForceSize];
    bridge::encode(m, std::span<std::uint8_t, bridge::kForceSize>(buffer));
    const ssize_t n = ::sendto(mSocket, buffer, sizeof buffer, MSG_DONTWAIT | MSG_NOSIGNAL,
                               reinterpret_cast<const sockaddr*>(&mPeer), mPeerLength);
    bump(n == static_cast<ssize_t>(sizeof buffer) ? mCounts.sent : mCounts.sendFailed);
}

}  // namespace palp::haptics
