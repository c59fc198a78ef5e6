#pragma once
/// @file
/// `palp serve --igtl-port`: an OpenIGTLink v2 server (libopenigtlink) that streams a running
/// session at display rate for 3D Slicer (OpenIGTLinkIF) or MITK: TRANSFORM `ProxyToRAS` and
/// `DeviceToRAS` (translation in RAS millimetres; rotation: the device's orientation in the
/// world, in RAS axes), SENSOR `Force` (3 values, newtons, RAS axes) and STATUS `Safety` (the
/// faults since the last frame: code 1 OK, 2 a fault or a scaled force, 15 force cut; subcode the
/// DeviceFault bits; docs/architecture.md, "Faults"). palp's world is LPS metres; RAS = (-x,
/// -y, z).
/// Built only when CMake finds OpenIGTLink (PALP_HAVE_OPENIGTLINK).

#include <Eigen/Core>
#include <atomic>
#include <cstdint>
#include <functional>
#include <thread>

#include "palp/haptics/session.h"

namespace palp::tool {

/// A thread that serves one OpenIGTLink client at a time on a TCP port: it reads the session's
/// newest snapshot (Session::latest(), so it is the session's one viewer thread) at @p rateHz
/// and sends the three messages; a client that goes away is dropped and the next one awaited.
class IgtlStream {
  public:
    /// Opens the server socket (@p port 0: any free port, see port()) and starts the thread. @p
    /// worldFromDevice (called on the stream's thread; empty: identity) gives the device's
    /// orientation in palp's world (LPS), drawn at both the device and the proxy. @throw
    /// palp::IoError naming the port when it cannot listen there.
    IgtlStream(haptics::Session& session, int port, double rateHz,
               std::function<Eigen::Matrix3d()> worldFromDevice = {});
    ~IgtlStream();  ///< stops and joins
    IgtlStream(const IgtlStream&) = delete;
    IgtlStream& operator=(const IgtlStream&) = delete;

    /// The bound TCP port (the one the system chose for port 0).
    int port() const noexcept { return mPort; }
    std::uint64_t framesSent() const noexcept { return mFrames.load(std::memory_order_relaxed); }
    std::uint64_t clients() const noexcept { return mClients.load(std::memory_order_relaxed); }

  private:
    void run() noexcept;
    void serve();
    haptics::Session& mSession;
    int mPort;
    double mRate;
    std::function<Eigen::Matrix3d()> mWorldFromDevice;
    struct Server;
    Server* mServer;
    std::atomic<bool> mStop{false};
    std::atomic<std::uint64_t> mFrames{0}, mClients{0};
    std::thread mThread;
};

}  // namespace palp::tool
