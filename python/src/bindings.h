#pragma once
/// @file
/// The palp Python module's parts (one file per idea) and the helpers they share.

#include <pybind11/pybind11.h>

#include <string>

namespace palp::python {

namespace py = pybind11;

void bindErrors(py::module_& m);       // module.cpp: palp exceptions as Python ones
void bindVolume(py::module_& m);       // volume.cpp: Volume, load, save, convert, phantom
void bindNumpyVolume(py::module_& m);  // numpy_volume.cpp: to_numpy, from numpy arrays
void bindParams(py::module_& m);       // params.cpp: coupling, proxy, session parameters
void bindSkin(py::module_& m);         // skin.cpp: SkinPatch, SkinField (paths on the skin)
void bindDevices(py::module_& m);      // devices.cpp: specs, trajectories, simulated, playback
void bindSession(py::module_& m);      // session.cpp: Scene, Session, Snapshot, traces
void bindMaps(py::module_& m);         // maps.cpp: MapPlane, Map, bin_trace, studies' tools
void bindBridge(py::module_& m);       // bridge.cpp: UdpDevice, UdpBridgeClient
void bindStudy(py::module_& m);        // study.cpp: Study (a perception study for a viewer)

/// Sets the attributes named by @p kwargs on @p object (a pybind11 instance of a bound class);
/// an unknown name raises AttributeError, so keyword constructors refuse misspelt fields.
void setAttributes(py::handle object, const py::kwargs& kwargs);

/// A keyword constructor for a plain struct bound with def_readwrite / def_property:
/// `palp.HandModel(mass_kg=0.2)`.
template <class T>
std::unique_ptr<T> fromKwargs(const py::kwargs& kwargs) {
    auto value = std::make_unique<T>();
    setAttributes(py::cast(value.get(), py::return_value_policy::reference), kwargs);
    return value;
}

}  // namespace palp::python
