// Volumes and numpy: Volume.to_numpy() (dense copy of the active box and its index-to-world
// affine) and the array side of palp.volume_from_numpy() (palp/__init__.py normalises the
// array first: dtype, byte order, negative strides).
#include <openvdb/tools/Dense.h>
#include <pybind11/eigen.h>
#include <pybind11/numpy.h>
#include <pybind11/stl.h>

#include <memory>
#include <optional>
#include <string>

#include "bindings.h"
#include "palp/base/error.h"
#include "palp/volume/from_memory.h"
#include "palp/volume/resample.h"

namespace palp::python {

using volume::Volume;

namespace {

/// LPS metres -> @p frame ("LPS" or "RAS") in @p units ("m" or "mm"), applied to the rows of an
/// index-to-world affine (it is its own inverse for the frame flip).
void checkFrame(const std::string& frame, const std::string& units) {
    if (frame != "LPS" && frame != "RAS") {
        throw ValueError("frame: expected 'LPS' or 'RAS', found '" + frame + "'");
    }
    if (units != "m" && units != "mm") {
        throw ValueError("units: expected 'm' or 'mm', found '" + units + "'");
    }
}

Eigen::Matrix4d fromLpsMetres(Eigen::Matrix4d a, const std::string& frame,
                              const std::string& units) {
    checkFrame(frame, units);
    if (frame == "RAS") a.topRows<2>() *= -1;
    if (units == "mm") a.topRows<3>() *= 1e3;
    return a;
}

volume::WorldFrame worldFrame(const std::string& frame, const std::string& units) {
    checkFrame(frame, units);
    if (frame == "LPS") {
        return units == "m" ? volume::WorldFrame::LpsMetres : volume::WorldFrame::LpsMillimetres;
    }
    return units == "m" ? volume::WorldFrame::RasMetres : volume::WorldFrame::RasMillimetres;
}

/// The grid's index-to-world map as a column-vector 4x4 (OpenVDB's Mat4 is row-vector).
Eigen::Matrix4d indexToWorld(const openvdb::FloatGrid& grid) {
    const openvdb::Mat4d m = grid.transform().baseMap()->getAffineMap()->getMat4();
    Eigen::Matrix4d a;
    for (int r = 0; r < 4; ++r)
        for (int c = 0; c < 4; ++c) a(r, c) = m(c, r);
    return a;
}

py::tuple toNumpy(const Volume& v, const std::string& frame, const std::string& units, int pad) {
    checkFrame(frame, units);
    if (pad < 0 || pad > 1000) {
        throw ValueError("pad: expected 0 to 1000 voxels, found " + std::to_string(pad));
    }
    openvdb::CoordBBox box = v.grid->evalActiveVoxelBoundingBox();
    if (!box.empty()) box.expand(pad);
    const Eigen::Matrix4d map = indexToWorld(*v.grid);
    if (box.empty()) {
        return py::make_tuple(py::array_t<float>(std::vector<py::ssize_t>{0, 0, 0}),
                              fromLpsMetres(map, frame, units));
    }
    const openvdb::Coord dim = box.dim();
    py::array_t<float> values(std::vector<py::ssize_t>{dim.x(), dim.y(), dim.z()});
    // LayoutZYX (VDB's own order): z fastest, so a C-ordered (nx, ny, nz) array holds voxel (i, j,
    // k) at [i, j, k].
    openvdb::tools::Dense<float, openvdb::tools::LayoutZYX> dense(box, values.mutable_data());
    {
        py::gil_scoped_release release;
        openvdb::tools::copyToDense(*v.grid, dense);  // inactive voxels: their stored value
    }
    Eigen::Matrix4d a = map;
    a.col(3) = map * Eigen::Vector4d(box.min().x(), box.min().y(), box.min().z(), 1.0);
    return py::make_tuple(values, fromLpsMetres(a, frame, units));
}

volume::ValueType valueType(const py::dtype& d) {
    const char kind = d.kind();
    const py::ssize_t size = d.itemsize();
    if (kind == 'i' && size == 1) return volume::ValueType::Int8;
    if (kind == 'u' && size == 1) return volume::ValueType::UInt8;
    if (kind == 'i' && size == 2) return volume::ValueType::Int16;
    if (kind == 'u' && size == 2) return volume::ValueType::UInt16;
    if (kind == 'i' && size == 4) return volume::ValueType::Int32;
    if (kind == 'u' && size == 4) return volume::ValueType::UInt32;
    if (kind == 'f' && size == 4) return volume::ValueType::Float32;
    if (kind == 'f' && size == 8) return volume::ValueType::Float64;
    throw ValueError(
        "numpy array: dtype: expected int8..int32, uint8..uint32, float32 or "
        "float64, found " +
        py::str(py::handle(d)).cast<std::string>());
}

std::shared_ptr<Volume> volumeFromArray(const py::array& array, const Eigen::Matrix4d& affine,
                                        const std::string& frame, const std::string& units,
                                        std::optional<double> voxelSize,
                                        std::optional<float> backgroundThreshold,
                                        const std::string& modality, const std::string& name) {
    if (array.ndim() != 3) {
        throw ValueError(name + ": expected a 3-D array (i, j, k), found " +
                         std::to_string(array.ndim()) + " dimensions");
    }
    volume::MemoryGrid g;
    g.data = array.data();
    g.type = valueType(array.dtype());
    for (int a = 0; a < 3; ++a) {
        g.dims[static_cast<std::size_t>(a)] = array.shape(a);
        g.strides[static_cast<std::size_t>(a)] = array.strides(a);
    }
    g.indexToWorld = affine;
    g.frame = worldFrame(frame, units);
    g.name = name;
    volume::ResampleOptions o;
    o.voxelSize = voxelSize;
    o.backgroundThreshold = backgroundThreshold;
    volume::checkResampleOptions(o);
    py::gil_scoped_release release;  // `array` stays referenced by the caller's frame
    volume::initialize();
    // The one copy: stackFromMemory converts the voxels to float slices (then resampled).
    volume::SliceStack stack = volume::stackFromMemory(g);
    stack.info.modality = modality;  // "CT": background -1000 HU, threshold -900 by default
    if (modality == "CT") stack.info.valueUnits = "HU";
    return std::make_shared<Volume>(volume::resample(stack, o));
}

}  // namespace

void bindNumpyVolume(py::module_& m) {
    auto cls =
        py::reinterpret_borrow<py::class_<Volume, std::shared_ptr<Volume>>>(m.attr("Volume"));
    cls.def("to_numpy", &toNumpy, py::arg("frame") = "LPS", py::arg("units") = "m",
            py::arg("pad") = 0,
            "(values, index_to_world): a dense float32 copy (C order, shape (nx, ny, nz)) of "
            "the active voxels' bounding box, inactive voxels holding their stored value (the "
            "background), and the 4x4 affine taking (i, j, k, 1) of the array to world "
            "coordinates in frame 'LPS' or 'RAS', units 'm' or 'mm'. pad widens the box by that "
            "many voxels on every side (pad=1 gives an array whose edge is background, which "
            "volume_from_numpy() turns back into the same volume: palp's resampler extends "
            "an array's edge values one voxel outward).");
    m.def("_volume_from_array", &volumeFromArray, py::arg("array"), py::arg("affine"),
          py::arg("frame"), py::arg("units"), py::arg("voxel_size"),
          py::arg("background_threshold"), py::arg("modality"), py::arg("name"));
}

}  // namespace palp::python
