// The device bridge (docs/device_bridge.md) from Python: palp.UdpDevice, a remote device's
// end in a session (palp serve's), and palp.UdpBridgeClient, the remote side (a device program
// written in Python, or a test's sender).
#include <pybind11/eigen.h>
#include <pybind11/stl.h>

#include <cstdint>
#include <memory>
#include <optional>
#include <string>

#include "bindings.h"
#include "palp/base/error.h"
#include "palp/haptics/devices/udp_bridge_client.h"
#include "palp/haptics/devices/udp_device.h"
#include "python_device.h"

namespace palp::python {

using haptics::Device;
using haptics::UdpBridgeClient;
using haptics::UdpDevice;
namespace bridge = haptics::bridge;

namespace {

py::dict countersDict(const haptics::UdpDeviceCounters& c) {
    py::dict d;
    d["received"] = c.received;
    d["superseded"] = c.superseded;
    d["lost"] = c.lost;
    d["late"] = c.late;
    d["restarts"] = c.restarts;
    d["peer_changes"] = c.peerChanges;
    d["ignored"] = c.ignored();
    d["short"] = c.shortDatagrams;
    d["bad_magic"] = c.badMagic;
    d["bad_version"] = c.badVersion;
    d["bad_type"] = c.badType;
    d["bad_size"] = c.badSize;
    d["receive_errors"] = c.receiveErrors;
    d["drain_limited"] = c.drainLimited;
    d["forces_sent"] = c.sent;
    d["forces_send_failed"] = c.sendFailed;
    return d;
}

py::dict stateDict(const bridge::StateMessage& m) {
    py::dict d;
    d["sequence"] = m.sequence;
    d["time_ns"] = m.timeNs;
    d["position"] = Eigen::Vector3d(m.position);
    const Eigen::Quaterniond& q = m.orientation;
    d["orientation"] = Eigen::Vector4d(q.w(), q.x(), q.y(), q.z());
    d["velocity"] = Eigen::Vector3d(m.velocity);
    d["buttons"] = m.buttons;
    return d;
}

py::dict forceDict(const bridge::ForceMessage& f) {
    py::dict d;
    d["sequence"] = f.sequence;
    d["time_ns"] = f.timeNs;
    d["force"] = Eigen::Vector3d(f.force);
    d["tick"] = f.tick;
    d["state_sequence"] = f.stateSequence;
    d["state_time_ns"] = f.stateTimeNs;
    d["force_scale"] = f.forceScale;
    d["flags"] = f.flags;
    d["stale"] = (f.flags & bridge::kForceStale) != 0;
    d["cut"] = (f.flags & bridge::kForceCut) != 0;
    // The state was refused (non-finite, out of range, too fast) or palp's force was faulted.
    d["fault"] = (f.flags & (bridge::kForceNonFiniteState | bridge::kForceOutOfRangeState |
                             bridge::kForceTooFastState | bridge::kForceNonFiniteForce |
                             bridge::kForceJump)) != 0;
    return d;
}

}  // namespace

void bindBridge(py::module_& m) {
    py::class_<UdpDevice, Device, std::shared_ptr<UdpDevice>>(
        m, "UdpDevice",
        "A remote device over the UDP device bridge (docs/device_bridge.md): States arrive on "
        "listen, each tick's force goes back to the newest State's sender; a watchdog cuts the "
        "force when States stop. The socket is bound here (port 0: any free one, see port). A "
        "palp device: Session(scene, device).start() runs it on the 1 kHz servo thread, or step "
        "it offline with run(n) (each tick reads what has arrived by then).")
        .def(py::init([](const std::string& listen, const std::string& spec, double timeout,
                         double grace, double resume, double period, int maxDrain) {
                 haptics::UdpDeviceParams p;
                 p.listen = listen;
                 p.watchdog.timeoutSeconds = timeout;
                 p.watchdog.graceSeconds = grace;
                 p.watchdog.resumeSeconds = resume;
                 p.periodSeconds = period;
                 p.maxDrain = maxDrain;
                 return std::make_shared<UdpDevice>(deviceSpecByName(spec), p);
             }),
             py::arg("listen") = "127.0.0.1:7405", py::kw_only(),
             py::arg("spec") = "3D Systems Touch X", py::arg("watchdog_timeout") = 10e-3,
             py::arg("watchdog_grace") = 2e-3, py::arg("watchdog_resume") = 50e-3,
             py::arg("period") = 1e-3, py::arg("max_drain") = 64,
             "listen: 'host:port' or '[ipv6]:port'; watchdog times in s; period: the servo "
             "period the watchdog counts in, s. Raises palp.ValueError for a bad address or "
             "parameter, palp.IoError when the port cannot be bound (e.g. EADDRINUSE).")
        .def_property_readonly("port", &UdpDevice::port, "The bound UDP port.")
        .def_property_readonly("address", &UdpDevice::address, "The bound 'host:port'.")
        .def(
            "counters", [](const UdpDevice& d) { return countersDict(d.counters()); },
            "What it has received and sent so far (any thread): received, lost, late, "
            "ignored (and by reason), forces_sent, ...")
        .def(
            "published_state", [](UdpDevice& d) { return stateDict(d.publishedState()); },
            "The newest accepted State as the servo thread published it (for a viewer: the "
            "orientation and buttons a Snapshot lacks); sequence 0 before any. One viewer "
            "thread.");

    py::class_<UdpBridgeClient>(
        m, "UdpBridgeClient",
        "The remote side of the bridge: sends States to a UdpDevice's address and receives its "
        "Forces (palp bridge-sim's; a device program written in Python). One thread at a "
        "time.")
        .def(py::init<std::string_view>(), py::arg("server"),
             "server: the UdpDevice's 'host:port'. Raises palp.ValueError / palp.IoError "
             "naming it.")
        .def(
            "send",
            [](UdpBridgeClient& c, std::uint64_t sequence, const Eigen::Vector3d& position,
               const Eigen::Vector3d& velocity, std::optional<Eigen::Vector4d> orientation,
               std::uint32_t buttons, std::uint64_t timeNs) {
                bridge::StateMessage s;
                s.sequence = sequence;
                s.timeNs = timeNs;
                s.position = position;
                s.velocity = velocity;
                if (orientation) {
                    const Eigen::Vector4d& q = *orientation;
                    s.orientation = Eigen::Quaterniond(q[0], q[1], q[2], q[3]);
                }
                s.buttons = buttons;
                return c.send(s);
            },
            py::arg("sequence"), py::arg("position"), py::arg("velocity") = Eigen::Vector3d::Zero(),
            py::kw_only(), py::arg("orientation") = py::none(), py::arg("buttons") = 0,
            py::arg("time_ns") = 0,
            "Sends one State (device frame: m, m/s; orientation (w, x, y, z), default "
            "identity) without waiting; False when the socket refused it.")
        .def(
            "send_raw",
            [](UdpBridgeClient& c, const py::bytes& data) {
                const std::string bytes = data;
                return c.sendRaw(
                    std::span(reinterpret_cast<const std::uint8_t*>(bytes.data()), bytes.size()));
            },
            py::arg("data"), "Sends any bytes (a malformed datagram).")
        .def(
            "receive",
            [](UdpBridgeClient& c, double timeout) -> py::object {
                bridge::ForceMessage f;
                bool got = false;
                {
                    py::gil_scoped_release release;
                    got = c.receive(f, timeout);
                }
                if (!got) return py::none();
                return forceDict(f);
            },
            py::arg("timeout") = 0.0,
            "The next Force as a dict (force, tick, state_sequence, state_time_ns, "
            "force_scale, flags, stale, cut, ...), waiting up to timeout s (GIL released); "
            "None when none came.")
        .def_property_readonly("ignored", &UdpBridgeClient::ignored)
        .def_property_readonly("local_port", &UdpBridgeClient::localPort);
}

}  // namespace palp::python
