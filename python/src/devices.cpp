// Devices: the specs of device classes, the hand model and scripted trajectories,
// SimulatedDevice and PlaybackDevice (drivable from Python too), and PythonDevice, a Device
// made of a Python object for offline sessions.
#include <pybind11/eigen.h>
#include <pybind11/stl.h>
#include <pybind11/stl/filesystem.h>

#include <cmath>
#include <limits>
#include <memory>
#include <string>

#include "bindings.h"
#include "palp/base/error.h"
#include "palp/haptics/devices/playback_device.h"
#include "palp/haptics/devices/simulated_device.h"
#include "palp/haptics/devices/trajectory.h"
#include "python_device.h"

namespace palp::python {

using haptics::Device;
using haptics::DeviceSpec;
using haptics::DeviceState;

const DeviceSpec& deviceSpecByName(const std::string& name) {
    if (const DeviceSpec* s = haptics::findDeviceSpec(name)) return *s;
    std::string names;
    for (const DeviceSpec& s : haptics::deviceSpecs()) {
        names += (names.empty() ? "'" : ", '") + std::string(s.name) + "'";
    }
    throw ValueError("device spec: expected one of " + names + ", found '" + name + "'");
}

PythonDevice::PythonDevice(py::object object, const DeviceSpec& spec)
    : mObject(std::move(object)), mSpec(spec) {
    if (!py::hasattr(mObject, "read") || !py::hasattr(mObject, "write")) {
        throw ValueError(
            "device: expected a palp device or an object with read() and "
            "write(force) methods, found " +
            py::repr(mObject).cast<std::string>());
    }
    mRead = mObject.attr("read");
    mWrite = mObject.attr("write");
}

PythonDevice::~PythonDevice() = default;

DeviceState PythonDevice::read() noexcept {
    DeviceState s;
    s.position.setConstant(std::numeric_limits<double>::quiet_NaN());
    if (mError) return s;  // a tick whose read already failed: NaN until raised
    try {
        const py::sequence r = mRead().cast<py::sequence>();
        const std::size_t n = r.size();
        if (n < 2 || n > 5) {
            throw ValueError(
                "device read(): expected (position, velocity[, buttons[, "
                "timestamp[, sequence]]]), found " +
                std::to_string(n) + " items");
        }
        s.position = r[0].cast<Eigen::Vector3d>();
        s.velocity = r[1].cast<Eigen::Vector3d>();
        if (n > 2) s.buttons = r[2].cast<std::uint32_t>();
        if (n > 3) s.timestampSeconds = r[3].cast<double>();
        s.sequence = n > 4 ? r[4].cast<std::uint64_t>() : ++mSequence;
    } catch (...) {
        mError = std::current_exception();
        s.position.setConstant(std::numeric_limits<double>::quiet_NaN());
    }
    return s;
}

void PythonDevice::write(const Eigen::Vector3d& forceN) noexcept {
    if (mError) return;
    try {
        mWrite(py::cast(Eigen::Vector3d(forceN)));
    } catch (...) {
        mError = std::current_exception();
    }
}

void PythonDevice::rethrow() {
    std::exception_ptr e = std::move(mError);
    mError = nullptr;
    std::rethrow_exception(e);
}

namespace {

/// read() for Python: (position, velocity, buttons).
py::tuple readState(Device& d) {
    const DeviceState s = d.read();
    return py::make_tuple(s.position, s.velocity, s.buttons);
}

template <class T>
py::class_<T> trajectory(py::module_& m, const char* name, const char* doc) {
    py::class_<T> cls(m, name, doc);
    cls.def(py::init(&fromKwargs<T>))
        .def(
            "sample",
            [](const T& t, double time) {
                Eigen::Vector3d p, v;
                t.sample(time, p, v);
                return py::make_tuple(p, v);
            },
            py::arg("t"), "(position, velocity) of the target at time t, s")
        .def_property(
            "skin", [](const T& t) { return std::const_pointer_cast<haptics::SkinField>(t.skin); },
            [](T& t, std::shared_ptr<haptics::SkinField> skin) { t.skin = std::move(skin); },
            "The palp.SkinField the path is laid on (its points then lie on the field's "
            "plane); None: the flat path.");
    return cls;
}

}  // namespace

void bindDevices(py::module_& m) {
    py::class_<DeviceSpec>(m, "DeviceSpec", "Limits of a device class (palp.device_specs()).")
        .def_property_readonly("name", [](const DeviceSpec& s) { return std::string(s.name); })
        .def_readonly("max_force", &DeviceSpec::maxForceN, "N")
        .def_readonly("max_continuous_force", &DeviceSpec::maxContinuousForceN, "N")
        .def_readonly("max_stiffness", &DeviceSpec::maxStiffnessNpm, "N/m")
        .def_readonly("max_damping", &DeviceSpec::maxDampingNspm, "N s/m")
        .def("__repr__",
             [](const DeviceSpec& s) { return "<palp.DeviceSpec '" + std::string(s.name) + "'>"; });
    m.def(
        "device_specs",
        [] {
            py::list l;
            for (const DeviceSpec& s : haptics::deviceSpecs()) {
                l.append(py::cast(&s, py::return_value_policy::reference));
            }
            return l;
        },
        "The device classes palp knows (name, force and stiffness limits).");
    m.def("device_spec", &deviceSpecByName, py::return_value_policy::reference, py::arg("name"));

    py::class_<haptics::HandModel>(m, "HandModel",
                                   "The simulated hand: mass, spring and damper to the target.")
        .def(py::init(&fromKwargs<haptics::HandModel>))
        .def_readwrite("mass_kg", &haptics::HandModel::massKg)
        .def_readwrite("stiffness", &haptics::HandModel::stiffnessNpm, "N/m")
        .def_readwrite("damping", &haptics::HandModel::dampingNspm, "N s/m");

    using haptics::PressTrajectory;
    trajectory<PressTrajectory>(m, "PressTrajectory",
                                "Press from start along direction by depth, hold, return.")
        .def_readwrite("start", &PressTrajectory::start)
        .def_readwrite("direction", &PressTrajectory::direction)
        .def_readwrite("depth", &PressTrajectory::depthM)
        .def_readwrite("press_seconds", &PressTrajectory::pressSeconds)
        .def_readwrite("hold_seconds", &PressTrajectory::holdSeconds);
    using haptics::SweepTrajectory;
    trajectory<SweepTrajectory>(m, "SweepTrajectory", "Back and forth along a line, pressed.")
        .def_readwrite("centre", &SweepTrajectory::centre)
        .def_readwrite("direction", &SweepTrajectory::direction)
        .def_readwrite("press_direction", &SweepTrajectory::pressDirection)
        .def_readwrite("length", &SweepTrajectory::lengthM)
        .def_readwrite("speed", &SweepTrajectory::speedMps)
        .def_readwrite("depth", &SweepTrajectory::depthM)
        .def_readwrite("approach", &SweepTrajectory::approachM)
        .def_readwrite("approach_seconds", &SweepTrajectory::approachSeconds)
        .def_readwrite("turn_seconds", &SweepTrajectory::turnSeconds);
    using haptics::RasterTrajectory;
    trajectory<RasterTrajectory>(m, "RasterTrajectory", "Boustrophedon raster, pressed.")
        .def_readwrite("centre", &RasterTrajectory::centre)
        .def_readwrite("u", &RasterTrajectory::u)
        .def_readwrite("v", &RasterTrajectory::v)
        .def_readwrite("press_direction", &RasterTrajectory::pressDirection)
        .def_readwrite("extent_u", &RasterTrajectory::extentU)
        .def_readwrite("extent_v", &RasterTrajectory::extentV)
        .def_readwrite("line_spacing", &RasterTrajectory::lineSpacingM)
        .def_readwrite("speed", &RasterTrajectory::speedMps)
        .def_readwrite("depth", &RasterTrajectory::depthM)
        .def_readwrite("approach", &RasterTrajectory::approachM)
        .def_readwrite("approach_seconds", &RasterTrajectory::approachSeconds)
        .def_readwrite("ramp_seconds", &RasterTrajectory::rampSeconds)
        .def_property_readonly("duration", &RasterTrajectory::durationSeconds, "s");
    using haptics::CircleTrajectory;
    trajectory<CircleTrajectory>(m, "CircleTrajectory", "Circles in the (u, v) plane, pressed.")
        .def_readwrite("centre", &CircleTrajectory::centre)
        .def_readwrite("u", &CircleTrajectory::u)
        .def_readwrite("v", &CircleTrajectory::v)
        .def_readwrite("press_direction", &CircleTrajectory::pressDirection)
        .def_readwrite("radius", &CircleTrajectory::radiusM)
        .def_readwrite("frequency", &CircleTrajectory::frequencyHz)
        .def_readwrite("depth", &CircleTrajectory::depthM)
        .def_readwrite("approach", &CircleTrajectory::approachM)
        .def_readwrite("approach_seconds", &CircleTrajectory::approachSeconds)
        .def_readwrite("ramp_seconds", &CircleTrajectory::rampSeconds);
    using haptics::SinusoidTrajectory;
    trajectory<SinusoidTrajectory>(m, "SinusoidTrajectory", "start + a(t) sin(2 pi f t) dir.")
        .def_readwrite("start", &SinusoidTrajectory::start)
        .def_readwrite("direction", &SinusoidTrajectory::direction)
        .def_readwrite("amplitude", &SinusoidTrajectory::amplitudeM)
        .def_readwrite("frequency", &SinusoidTrajectory::frequencyHz)
        .def_readwrite("grow_seconds", &SinusoidTrajectory::growSeconds);

    py::class_<Device, std::shared_ptr<Device>>(m, "Device", "A palp device (C++).")
        .def("read", &readState,
             "Advances the device one period: (position, velocity, buttons), device frame")
        .def(
            "write", [](Device& d, const Eigen::Vector3d& f) { d.write(f); }, py::arg("force"),
            "Sets the force, N, device frame")
        .def_property_readonly("spec", &Device::spec, py::return_value_policy::reference);

    py::class_<haptics::SimulatedDevice, Device, std::shared_ptr<haptics::SimulatedDevice>>(
        m, "SimulatedDevice",
        "A hand model following a scripted trajectory under the rendered force.")
        .def(py::init([](const haptics::Trajectory& trajectory, const std::string& spec,
                         const haptics::HandModel& hand, double period) {
                 return std::make_shared<haptics::SimulatedDevice>(deviceSpecByName(spec),
                                                                   trajectory, hand, period);
             }),
             py::arg("trajectory"), py::kw_only(), py::arg("spec") = "3D Systems Touch",
             py::arg("hand") = haptics::HandModel{}, py::arg("period") = 1e-3)
        .def_property_readonly("applied_force", &haptics::SimulatedDevice::appliedForce)
        .def_property_readonly("work_on_hand", &haptics::SimulatedDevice::workOnHand, "J");

    py::class_<haptics::PlaybackDevice, Device, std::shared_ptr<haptics::PlaybackDevice>>(
        m, "PlaybackDevice", "Replays a device log (CSV: t,x,y,z,vx,vy,vz,buttons,fx,fy,fz).")
        .def(py::init([](const std::filesystem::path& log, const std::string& spec, double period) {
                 std::vector<haptics::DeviceSample> samples;
                 {
                     py::gil_scoped_release release;
                     samples = haptics::readDeviceLog(log);
                 }
                 return std::make_shared<haptics::PlaybackDevice>(deviceSpecByName(spec),
                                                                  std::move(samples), period);
             }),
             py::arg("log"), py::kw_only(), py::arg("spec") = "3D Systems Touch",
             py::arg("period") = 1e-3)
        .def_property_readonly("finished", &haptics::PlaybackDevice::finished)
        .def_property_readonly("applied_force", &haptics::PlaybackDevice::appliedForce);
}

}  // namespace palp::python
