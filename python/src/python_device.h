#pragma once
/// @file
/// A Device whose samples come from a Python object (offline stepping only).

#include <pybind11/pybind11.h>

#include <exception>
#include <string>

#include "palp/haptics/devices/device.h"

namespace palp::python {

namespace py = pybind11;

/// The spec named @p name (deviceSpecs()); @throw ValueError listing the names.
const haptics::DeviceSpec& deviceSpecByName(const std::string& name);

/// Wraps a Python object with read() -> (position, velocity[, buttons[, timestamp[,
/// sequence]]]) and write(force) (force: numpy float64 (3,), N, device frame).
///
/// Called on the thread that steps the session, with the GIL held: a Session with a Python
/// device only steps offline (step(), run()); start() refuses it. An exception raised by the
/// object (or a malformed sample) is kept, read() returns NaN (held by the session's guard),
/// and the binding raises it after the tick (pending() / rethrow()).
class PythonDevice final : public haptics::Device {
  public:
    PythonDevice(py::object object, const haptics::DeviceSpec& spec);
    ~PythonDevice() override;

    haptics::DeviceState read() noexcept override;
    void write(const Eigen::Vector3d& forceN) noexcept override;
    const haptics::DeviceSpec& spec() const noexcept override { return mSpec; }

    bool pending() const noexcept { return static_cast<bool>(mError); }
    /// Raises the kept exception (and forgets it).
    [[noreturn]] void rethrow();

  private:
    py::object mObject, mRead, mWrite;
    const haptics::DeviceSpec& mSpec;
    std::exception_ptr mError;  // the first exception of a tick, raised after it
    std::uint64_t mSequence = 0;
};

}  // namespace palp::python
