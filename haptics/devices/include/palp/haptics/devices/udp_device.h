#pragma once
/// @file
/// A Device on the other side of a network: it receives the remote device's state as UDP
/// datagrams of the bridge protocol (bridge_protocol.h, docs/device_bridge.md) and sends the
/// force back, without ever blocking the servo thread; a watchdog cuts the force when the states
/// stop coming.

#include <sys/socket.h>

#include <Eigen/Core>
#include <atomic>
#include <cstdint>
#include <string>
#include <string_view>

#include "palp/base/nothrow_slot.h"
#include "palp/base/triple_buffer.h"
#include "palp/haptics/devices/bridge_protocol.h"
#include "palp/haptics/devices/device.h"
#include "palp/haptics/devices/watchdog_device.h"

namespace palp::haptics {

/// A host (numeric IPv4 / IPv6 address or a name) and a UDP port.
struct UdpEndpoint {
    std::string host;
    std::uint16_t port = 0;
};

/// Parses "host:port" or "[ipv6]:port" (port 0..65535; 0 on a listening side: any free port).
/// @throw palp::ValueError naming @p what and the text: `--listen 'foo': expected host:port ...`.
UdpEndpoint parseUdpEndpoint(std::string_view text, std::string_view what);

/// How a UdpDevice listens and when its force is cut.
struct UdpDeviceParams {
    /// Local address to bind, "host:port" (port 0: any free one, see UdpDevice::port()).
    std::string listen = "127.0.0.1:7405";
    /// The force is cut when no fresh state arrives (WatchdogDevice; times in servo periods).
    WatchdogParams watchdog;
    double periodSeconds = 1e-3;  ///< the servo period the watchdog counts in, s
    /// Most datagrams one read() takes from the socket (1..4096); more stay for the next read.
    int maxDrain = 64;
    /// Kernel receive buffer asked for (SO_RCVBUF), bytes (0: the system's default).
    int receiveBufferBytes = 1 << 18;
};

/// @throw palp::ValueError naming the field.
void validateUdpDeviceParams(const UdpDeviceParams& params);

/// What a UdpDevice has seen and sent so far (read from any thread, each count on its own).
struct UdpDeviceCounters {
    std::uint64_t received = 0;        ///< state datagrams accepted
    std::uint64_t superseded = 0;      ///< accepted, but a newer one arrived in the same read()
    std::uint64_t lost = 0;            ///< sequence numbers skipped by accepted datagrams
    std::uint64_t late = 0;            ///< not newer than the last accepted (ignored)
    std::uint64_t restarts = 0;        ///< the sender's sequence fell back by > kRestartGap
    std::uint64_t peerChanges = 0;     ///< a state came from another address than the last one
    std::uint64_t shortDatagrams = 0;  ///< ignored: fewer than 8 bytes
    std::uint64_t badMagic = 0;        ///< ignored: not "PLPB" (foreign datagrams)
    std::uint64_t badVersion = 0;      ///< ignored: a protocol version other than 1
    std::uint64_t badType = 0;         ///< ignored: not a state message
    std::uint64_t badSize = 0;         ///< ignored: a state message of the wrong size
    std::uint64_t receiveErrors = 0;   ///< recvfrom failed other than "nothing queued"
    std::uint64_t drainLimited = 0;    ///< read()s that stopped at maxDrain datagrams
    std::uint64_t sent = 0;            ///< force datagrams sent
    std::uint64_t sendFailed = 0;      ///< force datagrams the socket refused (full, no route)

    /// Datagrams ignored as malformed or foreign (short, magic, version, type, size).
    std::uint64_t ignored() const noexcept {
        return shortDatagrams + badMagic + badVersion + badType + badSize;
    }
};

/// A Device whose states arrive as bridge StateMessages on a UDP socket and whose force goes
/// back as ForceMessages to the address the newest state came from.
///
/// read() drains the socket without waiting (at most maxDrain recvfrom calls with MSG_DONTWAIT);
/// the newest accepted state wins: a datagram is accepted when it decodes as a StateMessage and
/// its sequence is newer than the last accepted one from the same address (a new address, or a
/// sequence fallen back by more than kRestartGap, starts the count afresh); gaps between accepted
/// sequences are counted as lost. Everything else is ignored and counted (UdpDeviceCounters).
/// The state goes through a WatchdogDevice (UdpDeviceParams::watchdog), so health() reports
/// staleness and a sender that stops gets zero force within the watchdog's timeout (Session
/// scales its force by health().forceScale). Until the first state arrives read() returns the
/// device at rest at the origin and health() says stale with force scale 0.
///
/// write() sends one ForceMessage (sendto with MSG_DONTWAIT; a full socket drops it, counted)
/// with the force clamped to forceScale x maxForceN, the tick (the number of write() calls
/// before this one: Snapshot::tick when the device serves one session from its first tick), the
/// newest state's sequence and time echoed, the scale and ForceFlag bits: the watchdog's, and
/// the session's when it called reportFaults() before this write() (Session does every tick:
/// the scale is then the smaller, the fault bits of both are set). Before any state has arrived
/// nothing is sent (there is nobody to send to).
///
/// @par Threading  read(), write(), health() and latestState() from the servo thread only;
///      publishedState() from one viewer thread; counters(), port() and address() from any.
/// @par Real-time  read() and write() are noexcept, allocation-free and bounded (maxDrain + 1
///      non-blocking system calls); the constructor does all set-up.
class UdpDevice final : public Device {
  public:
    /// A sequence that falls back by more than this is a restarted sender, not a late datagram.
    static constexpr std::uint64_t kRestartGap = 1024;

    /// Opens and binds the socket.
    /// @throw palp::ValueError for bad params or an address that does not parse or resolve
    ///        (naming it); palp::IoError when the socket cannot be opened or bound (the address
    ///        and the system's reason, e.g. `Address already in use (EADDRINUSE)`).
    UdpDevice(const DeviceSpec& spec, const UdpDeviceParams& params);
    ~UdpDevice() override;
    UdpDevice(const UdpDevice&) = delete;
    UdpDevice& operator=(const UdpDevice&) = delete;

    DeviceState read() noexcept override;
    void write(const Eigen::Vector3d& forceN) noexcept override;
    const DeviceSpec& spec() const noexcept override { return mSpec; }
    /// The watchdog's; before the first state: stale, force scale 0 (no force is rendered).
    DeviceHealth health() const noexcept override;
    /// Kept for the next write()'s Force flags and scale.
    void reportFaults(std::uint32_t faults, double forceScale) noexcept override;

    /// The bound port (the one the system chose for port 0).
    std::uint16_t port() const noexcept { return mPort; }
    /// The bound address as "host:port".
    const std::string& address() const noexcept { return mAddress; }
    /// A copy of the counts so far.
    UdpDeviceCounters counters() const noexcept;
    /// The newest accepted state (orientation and buttons included); servo thread only.
    const bridge::StateMessage& latestState() const noexcept { return mState; }
    /// Whether any state has been accepted; servo thread only.
    bool hasState() const noexcept { return mHasState; }
    /// One viewer thread (e.g. a display-rate stream): the newest accepted state as the servo
    /// thread published it (lock-free, may skip states); sequence 0 before any. Use it for
    /// what a Snapshot lacks: the orientation and the buttons.
    const bridge::StateMessage& publishedState() noexcept { return mPublished.read().value; }

  private:
    /// The socket as a Device, watched by mWatchdog.
    class Link final : public Device {
      public:
        explicit Link(UdpDevice& owner) : mOwner(owner) {}
        DeviceState read() noexcept override;
        void write(const Eigen::Vector3d&) noexcept override {}
        const DeviceSpec& spec() const noexcept override { return mOwner.mSpec; }

      private:
        UdpDevice& mOwner;
    };
    void drain() noexcept;
    void accept(const bridge::StateMessage& m, const sockaddr_storage& from,
                socklen_t fromLength) noexcept;

    DeviceSpec mSpec;
    UdpDeviceParams mParams;
    int mSocket = -1;
    std::uint16_t mPort = 0;
    std::string mAddress;
    Link mLink{*this};
    WatchdogDevice mWatchdog;
    // Servo thread's state.
    bridge::StateMessage mState;
    DeviceState mDeviceState;
    bool mHasState = false;
    sockaddr_storage mPeer{};
    socklen_t mPeerLength = 0;
    std::uint64_t mWrites = 0;
    std::uint64_t mWaitingReads = 0;  // reads before the first state
    std::uint64_t mSendSequence = 0;
    bool mReported = false;  // reportFaults() since the last write()
    std::uint32_t mReportedFaults = 0;
    double mReportedScale = 1;
    TripleBuffer<NothrowSlot<bridge::StateMessage>> mPublished;  // servo -> viewer
    // Counts: written by the servo thread (relaxed), read by any.
    struct AtomicCounters {
        std::atomic<std::uint64_t> received{0}, superseded{0}, lost{0}, late{0}, restarts{0},
            peerChanges{0}, shortDatagrams{0}, badMagic{0}, badVersion{0}, badType{0}, badSize{0},
            receiveErrors{0}, drainLimited{0}, sent{0}, sendFailed{0};
    } mCounts;
};

}  // namespace palp::haptics
