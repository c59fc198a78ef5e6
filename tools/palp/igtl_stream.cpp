#include "igtl_stream.h"

#include <igtlClientSocket.h>
#include <igtlMath.h>
#include <igtlSensorMessage.h>
#include <igtlServerSocket.h>
#include <igtlStatusMessage.h>
#include <igtlTransformMessage.h>
#include <igtlUnit.h>
#include <igtl_unit.h>

#include <array>
#include <chrono>
#include <cstdint>
#include <string>
#include <utility>

#include "palp/base/error.h"

namespace palp::tool {

struct IgtlStream::Server {
    igtl::ServerSocket::Pointer socket = igtl::ServerSocket::New();
};

namespace {

/// LPS metres -> RAS millimetres.
Eigen::Vector3d rasMm(const Eigen::Vector3d& lpsM) {
    return Eigen::Vector3d(-lpsM.x(), -lpsM.y(), lpsM.z()) * 1e3;
}

/// A pose at @p lpsM with orientation @p worldFromDevice (LPS axes), in RAS: the rotation's
/// columns (the device's axes) and the translation with x and y negated, the translation in mm.
igtl::TransformMessage::Pointer transform(const char* name, const Eigen::Vector3d& lpsM,
                                          const Eigen::Matrix3d& worldFromDevice,
                                          igtl::TimeStamp::Pointer& ts) {
    igtl::Matrix4x4 m;
    igtl::IdentityMatrix(m);
    const Eigen::Matrix3d rasFromDevice = Eigen::Vector3d(-1, -1, 1).asDiagonal() * worldFromDevice;
    const Eigen::Vector3d r = rasMm(lpsM);
    for (int i = 0; i < 3; ++i) {
        for (int j = 0; j < 3; ++j) m[i][j] = static_cast<float>(rasFromDevice(i, j));
        m[i][3] = static_cast<float>(r[i]);
    }
    auto msg = igtl::TransformMessage::New();
    msg->SetDeviceName(name);
    msg->SetMatrix(m);
    msg->SetTimeStamp(ts);
    msg->Pack();
    return msg;
}

igtl::SensorMessage::Pointer force(const Eigen::Vector3d& lpsN, igtl::TimeStamp::Pointer& ts) {
    auto unit = igtl::Unit::New();
    unit->SetPrefix(IGTL_UNIT_PREFIX_NONE);
    unit->Append(IGTL_UNIT_SI_DERIVED_NEWTON, 1);
    auto msg = igtl::SensorMessage::New();
    msg->SetDeviceName("Force");
    msg->SetLength(3);
    msg->SetUnit(unit);
    msg->SetValue(0, -lpsN.x());  // RAS axes, N
    msg->SetValue(1, -lpsN.y());
    msg->SetValue(2, lpsN.z());
    msg->SetTimeStamp(ts);
    msg->Pack();
    return msg;
}

/// The sum of the fault counts, one per DeviceFault bit in bit order.
std::array<std::uint64_t, 8> faultCounts(const haptics::Snapshot& s) {
    const haptics::FaultCounts& c = s.faultCounts;
    return {c.stale,          c.nonFinite, c.outOfRange, c.tooFast,
            c.forceNonFinite, c.forceJump, c.overload,   c.shed};
}

/// STATUS `Safety`: the faults of the ticks since the last frame (a fault that lasted one tick
/// between two frames shows too) and the force's scale. Code: 1 OK (no fault, whole force),
/// 2 UNKNOWN_ERROR (a fault, or a force scaled down), 15 DISABLED (force cut to zero); subcode:
/// the DeviceFault bits; error name: the first fault's name; status: counts and scale.
igtl::StatusMessage::Pointer safety(const haptics::Snapshot& s, std::uint32_t sinceLast,
                                    igtl::TimeStamp::Pointer& ts) {
    static constexpr std::array<const char*, 8> kNames = {
        "stale",      "non-finite", "out-of-range", "too-fast", "force-non-finite",
        "force-jump", "overload",   "shed"};
    const std::uint32_t bits = sinceLast | s.faultFlags;
    const char* first = "";
    std::string text;
    for (std::size_t i = 0; i < kNames.size(); ++i) {
        if (!(bits & (1u << i))) continue;
        if (!*first) first = kNames[i];
        text += std::string(text.empty() ? "" : ", ") + kNames[i];
    }
    const haptics::FaultCounts& c = s.faultCounts;
    text += std::string(text.empty() ? "no fault" : "") + "; force scale " +
            std::to_string(s.deviceForceScale) + "; ticks stale " + std::to_string(c.stale) +
            ", non-finite " + std::to_string(c.nonFinite) + ", out of range " +
            std::to_string(c.outOfRange) + ", too fast " + std::to_string(c.tooFast) +
            ", force non-finite " + std::to_string(c.forceNonFinite) + ", force jump " +
            std::to_string(c.forceJump) + ", overload " + std::to_string(c.overload) + ", shed " +
            std::to_string(c.shed) + "; trips " + std::to_string(s.watchdogTrips + s.faultTrips);
    auto msg = igtl::StatusMessage::New();
    msg->SetDeviceName("Safety");
    msg->SetCode(s.deviceForceScale <= 0                 ? igtl::StatusMessage::STATUS_DISABLED
                 : (bits != 0 || s.deviceForceScale < 1) ? igtl::StatusMessage::STATUS_UNKNOWN_ERROR
                                                         : igtl::StatusMessage::STATUS_OK);
    msg->SetSubCode(static_cast<igtlInt64>(bits));
    msg->SetErrorName(bits ? first : "");
    msg->SetStatusString(text.c_str());
    msg->SetTimeStamp(ts);
    msg->Pack();
    return msg;
}

}  // namespace

IgtlStream::IgtlStream(haptics::Session& session, int port, double rateHz,
                       std::function<Eigen::Matrix3d()> worldFromDevice)
    : mSession(session),
      mPort(port),
      mRate(rateHz),
      mWorldFromDevice(std::move(worldFromDevice)),
      mServer(new Server) {
    if (mServer->socket->CreateServer(port) < 0) {
        delete mServer;
        throw IoError("--igtl-port " + std::to_string(port) +
                      ": expected a free TCP port to serve OpenIGTLink on, found it in use or "
                      "refused");
    }
    if (port == 0) mPort = mServer->socket->GetServerPort();
    mThread = std::thread([this] { run(); });
}

IgtlStream::~IgtlStream() {
    mStop.store(true);
    if (mThread.joinable()) mThread.join();
    mServer->socket->CloseSocket();
    delete mServer;
}

void IgtlStream::run() noexcept {
    try {
        serve();
    } catch (...) {
        // Out of memory in the library: the stream stops, the session runs on.
    }
}

void IgtlStream::serve() {
    using Clock = std::chrono::steady_clock;
    const auto period =
        std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double>(1.0 / mRate));
    igtl::ClientSocket::Pointer client;
    auto next = Clock::now();
    std::array<std::uint64_t, 8> counted{};  // the fault counts of the last frame sent
    while (!mStop.load()) {
        if (!client || !client->GetConnected()) {
            client = mServer->socket->WaitForConnection(100);  // ms; then look at mStop again
            if (client) {
                client->SetSendTimeout(200);  // a stalled viewer cannot hold this thread long
                mClients.fetch_add(1, std::memory_order_relaxed);
                next = Clock::now();
            }
            continue;
        }
        const haptics::Snapshot s = mSession.latest();
        auto ts = igtl::TimeStamp::New();
        ts->GetTime();
        const Eigen::Matrix3d rotation =
            mWorldFromDevice ? mWorldFromDevice() : Eigen::Matrix3d::Identity();
        const auto proxy = transform("ProxyToRAS", s.proxy, rotation, ts);
        const auto device = transform("DeviceToRAS", s.probe, rotation, ts);
        const auto f = force(s.force, ts);
        const std::array<std::uint64_t, 8> counts = faultCounts(s);
        std::uint32_t since = 0;
        for (std::size_t i = 0; i < counts.size(); ++i)
            if (counts[i] > counted[i]) since |= 1u << i;
        counted = counts;
        const auto status = safety(s, since, ts);
        const bool ok = client->Send(proxy->GetPackPointer(), proxy->GetPackSize()) &&
                        client->Send(device->GetPackPointer(), device->GetPackSize()) &&
                        client->Send(f->GetPackPointer(), f->GetPackSize()) &&
                        client->Send(status->GetPackPointer(), status->GetPackSize());
        if (!ok) {
            client->CloseSocket();
            client = nullptr;
            continue;
        }
        mFrames.fetch_add(1, std::memory_order_relaxed);
        next += period;
        std::this_thread::sleep_until(next);
    }
    if (client) client->CloseSocket();
}

}  // namespace palp::tool
