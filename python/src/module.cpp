// The palp extension module: palp's exceptions as Python exceptions, then the parts.
#include <pybind11/pybind11.h>

#include "bindings.h"
#include "palp/base/error.h"
#include "palp/volume/volume.h"

namespace palp::python {

void setAttributes(py::handle object, const py::kwargs& kwargs) {
    for (const auto& [name, value] : kwargs) {
        py::setattr(object, name, value);
    }
}

namespace {

/// A new exception class palp.<name> with @p bases (a tuple of classes), owned by the module.
py::object makeException(py::module_& m, const char* name, py::tuple bases, const char* doc) {
    const std::string full = std::string("palp.") + name;
    py::object type = py::reinterpret_steal<py::object>(
        PyErr_NewExceptionWithDoc(full.c_str(), doc, bases.ptr(), nullptr));
    if (!type) throw py::error_already_set();
    m.attr(name) = type;
    return type;
}

}  // namespace

void bindErrors(py::module_& m) {
    // palp.Error is the base of all; ValueError and FormatError are also Python ValueErrors,
    // IoError an OSError, so callers that catch the builtin kinds keep working.
    py::object error = makeException(m, "Error", py::make_tuple(py::handle(PyExc_RuntimeError)),
                                     "Base of palp's errors (palp::Error).");
    py::object value =
        makeException(m, "ValueError", py::make_tuple(error, py::handle(PyExc_ValueError)),
                      "A value palp refuses (palp::ValueError), named in the text.");
    py::object format =
        makeException(m, "FormatError", py::make_tuple(value),
                      "A file palp cannot read as its format (palp::FormatError); names the file.");
    py::object io = makeException(m, "IoError", py::make_tuple(error, py::handle(PyExc_OSError)),
                                  "A file that cannot be opened, read or written (palp::IoError).");
    // The translator runs with the GIL held. The classes are kept for the process's life (a
    // static py::object would be released after the interpreter is gone).
    static PyObject* const sError = error.inc_ref().ptr();
    static PyObject* const sValue = value.inc_ref().ptr();
    static PyObject* const sFormat = format.inc_ref().ptr();
    static PyObject* const sIo = io.inc_ref().ptr();
    py::register_exception_translator([](std::exception_ptr p) {
        try {
            if (p) std::rethrow_exception(p);
        } catch (const palp::FormatError& e) {
            PyErr_SetString(sFormat, e.what());
        } catch (const palp::IoError& e) {
            PyErr_SetString(sIo, e.what());
        } catch (const palp::ValueError& e) {
            PyErr_SetString(sValue, e.what());
        } catch (const palp::Error& e) {
            PyErr_SetString(sError, e.what());
        }
    });
}

}  // namespace palp::python

PYBIND11_MODULE(_palp, m) {
    using namespace palp::python;
    m.doc() = "palp: haptic volume palpation (C++ core; see the palp package for the API)";
    palp::volume::initialize();
    bindErrors(m);
    bindVolume(m);
    bindNumpyVolume(m);
    bindParams(m);
    bindSkin(m);  // before the trajectories, whose skin is a SkinField
    bindDevices(m);
    bindSession(m);
    bindMaps(m);
    bindBridge(m);
    bindStudy(m);
}
