#include "igtl_stream.h"

#include <igtlClientSocket.h>
#include <igtlMath.h>
#include <igtlSensorMessage.h>
#include <igtlServerSocket.h>
#include <igtlTransformMessage.h>
#include <igtlUnit.h>
#include <igtl_unit.h>

#include <chrono>
#include <string>

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

igtl::TransformMessage::Pointer transform(const char* name, const Eigen::Vector3d& lpsM,
                                          igtl::TimeStamp::Pointer& ts) {
    igtl::Matrix4x4 m;
    igtl::IdentityMatrix(m);
    const Eigen::Vector3d r = rasMm(lpsM);
    for (int i = 0; i < 3; ++i) m[i][3] = static_cast<float>(r[i]);
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

}  // namespace

IgtlStream::IgtlStream(haptics::Session& session, int port, double rateHz)
    : mSession(session), mPort(port), mRate(rateHz), mServer(new Server) {
    if (mServer->socket->CreateServer(port) < 0) {
        delete mServer;
        throw IoError("--igtl-port " + std::to_string(port) +
                      ": expected a free TCP port to serve OpenIGTLink on, found it in use or "
                      "refused");
    }
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
        const auto proxy = transform("ProxyToRAS", s.proxy, ts);
        const auto device = transform("DeviceToRAS", s.probe, ts);
        const auto f = force(s.force, ts);
        const bool ok = client->Send(proxy->GetPackPointer(), proxy->GetPackSize()) &&
                        client->Send(device->GetPackPointer(), device->GetPackSize()) &&
                        client->Send(f->GetPackPointer(), f->GetPackSize());
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
