// Volumes: palp.Volume, load / save / convert (the GIL released while they run) and the thesis
// phantoms.
#include <pybind11/eigen.h>
#include <pybind11/stl.h>
#include <pybind11/stl/filesystem.h>

#include <filesystem>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "bindings.h"
#include "palp/base/error.h"
#include "palp/volume/load.h"
#include "palp/volume/phantom.h"

namespace palp::python {

namespace fs = std::filesystem;
using volume::Volume;

namespace {

/// One path or a list of them (several DICOM files of one series).
std::vector<fs::path> pathList(const py::object& inputs) {
    if (py::isinstance<py::str>(inputs) || py::hasattr(inputs, "__fspath__")) {
        return {inputs.cast<fs::path>()};
    }
    return inputs.cast<std::vector<fs::path>>();
}

volume::LoadOptions loadOptions(std::optional<double> voxelSize,
                                std::optional<float> backgroundThreshold,
                                std::optional<std::string> seriesUid,
                                std::optional<int> timePoint) {
    volume::LoadOptions o;
    o.resample.voxelSize = voxelSize;
    o.resample.backgroundThreshold = backgroundThreshold;
    o.seriesUid = std::move(seriesUid);
    o.timePoint = timePoint;
    return o;
}

volume::Compression parseCompression(const std::string& name) {
    if (name == "blosc") return volume::Compression::Blosc;
    if (name == "zip") return volume::Compression::Zip;
    if (name == "active-mask") return volume::Compression::ActiveMask;
    throw ValueError("compression: expected blosc, zip or active-mask, found '" + name + "'");
}

py::dict infoDict(const volume::VolumeInfo& i) {
    py::dict d;
    d["modality"] = i.modality;
    d["value_units"] = i.valueUnits;
    d["source_format"] = i.sourceFormat;
    d["source_description"] = i.sourceDescription;
    d["series_uid"] = i.seriesUid;
    d["original_dims"] = py::make_tuple(i.originalDims[0], i.originalDims[1], i.originalDims[2]);
    d["original_spacing"] =
        py::make_tuple(i.originalSpacing[0], i.originalSpacing[1], i.originalSpacing[2]);
    d["min_slice_gap"] = i.minSliceGap;
    d["max_slice_gap"] = i.maxSliceGap;
    d["rescale_slope"] = i.rescaleSlope;
    d["rescale_intercept"] = i.rescaleIntercept;
    d["gantry_tilt_deg"] = i.gantryTiltDeg;
    d["time_point"] = i.timePoint;
    d["time_point_count"] = i.timePointCount;
    d["background_threshold"] = i.backgroundThreshold;
    return d;
}

void saveVolume(const Volume& v, const fs::path& path, const std::string& compression) {
    volume::SaveOptions o;
    o.compression = parseCompression(compression);
    py::gil_scoped_release release;
    volume::save(v, path, o);
}

}  // namespace

void bindVolume(py::module_& m) {
    py::class_<Volume, std::shared_ptr<Volume>>(
        m, "Volume",
        "A scan as a sparse OpenVDB grid: isotropic axis-aligned voxels, world in LPS metres "
        "(+x left, +y posterior, +z superior). Make one with load(), phantom() or "
        "volume_from_numpy().")
        .def_property_readonly("voxel_size", &Volume::voxelSize, "voxel edge, m")
        .def_property_readonly(
            "info", [](const Volume& v) { return infoDict(v.info); },
            "acquisition facts (modality, value units, source format, ...) as a dict")
        .def_property_readonly(
            "world_bounds",
            [](const Volume& v) {
                const openvdb::BBoxd b = v.worldBounds();
                return py::make_tuple(Eigen::Vector3d(b.min().x(), b.min().y(), b.min().z()),
                                      Eigen::Vector3d(b.max().x(), b.max().y(), b.max().z()));
            },
            "(min, max): world box of the active voxels' centres, m (LPS)")
        .def_property_readonly("active_voxel_count",
                               [](const Volume& v) { return v.grid->activeVoxelCount(); })
        .def_property_readonly(
            "background", [](const Volume& v) { return v.grid->background(); },
            "value of inactive voxels (-1000 HU for CT)")
        .def("save", &saveVolume, py::arg("path"), py::arg("compression") = "active-mask",
             "Writes a .vdb (grid 'scan', metadata); active-mask (active values as plain "
             "floats), blosc (~15 % smaller for CT, ~3x the write time) or zip.")
        .def("__repr__", [](const Volume& v) {
            return "<palp.Volume " + std::to_string(v.grid->activeVoxelCount()) +
                   " active voxels, " + std::to_string(v.voxelSize() * 1e3) + " mm, '" +
                   v.info.sourceFormat + "'>";
        });

    m.def(
        "load",
        [](const py::object& inputs, std::optional<double> voxelSize,
           std::optional<float> backgroundThreshold, std::optional<std::string> seriesUid,
           std::optional<int> timePoint) {
            const std::vector<fs::path> paths = pathList(inputs);
            const volume::LoadOptions o =
                loadOptions(voxelSize, backgroundThreshold, std::move(seriesUid), timePoint);
            py::gil_scoped_release release;
            return std::make_shared<Volume>(volume::load(paths, o));
        },
        py::arg("inputs"), py::kw_only(), py::arg("voxel_size") = py::none(),
        py::arg("background_threshold") = py::none(), py::arg("series_uid") = py::none(),
        py::arg("time_point") = py::none(),
        "Reads a scan (DICOM folder or files, NIfTI, NRRD, MetaImage, .vdb) and resamples it "
        "to isotropic voxels of voxel_size metres (default: the finest input spacing). Raises "
        "palp.IoError / palp.FormatError / palp.ValueError naming the file.");

    m.def("save", &saveVolume, py::arg("volume"), py::arg("path"),
          py::arg("compression") = "active-mask",
          "Writes @p volume as a .vdb (compression as Volume.save).");

    m.def(
        "convert",
        [](const py::object& inputs, const fs::path& output, std::optional<double> voxelSize,
           std::optional<float> backgroundThreshold, std::optional<std::string> seriesUid,
           std::optional<int> timePoint, const std::string& compression) {
            const std::vector<fs::path> paths = pathList(inputs);
            const volume::LoadOptions o =
                loadOptions(voxelSize, backgroundThreshold, std::move(seriesUid), timePoint);
            volume::SaveOptions so;
            so.compression = parseCompression(compression);
            py::gil_scoped_release release;
            auto v = std::make_shared<Volume>(volume::load(paths, o));
            volume::save(*v, output, so);
            return v;
        },
        py::arg("inputs"), py::arg("output"), py::kw_only(), py::arg("voxel_size") = py::none(),
        py::arg("background_threshold") = py::none(), py::arg("series_uid") = py::none(),
        py::arg("time_point") = py::none(), py::arg("compression") = "active-mask",
        "load() then save() to a .vdb, as `palp convert` does; returns the volume.");

    m.def(
        "phantom",
        [](const std::string& scene, double voxelSize, int quadrant, const std::string& shape,
           int displacement, double boneTiltDeg, const std::string& profile, double transitionWidth,
           double hardDepth, const Eigen::Vector3d& inclusionCentre, double inclusionRadius,
           double fatThickness, double noiseSigmaHu, double blurSigma, int supersample,
           std::uint64_t seed, double margin) {
            volume::PhantomSpec s;
            s.params.scene = volume::parseScene(scene);
            s.params.quadrant = quadrant;
            s.params.shape = volume::parseShape(shape);
            s.params.displacement = displacement;
            s.params.boneTiltDeg = boneTiltDeg;
            s.params.profile = volume::parseProfile(profile);
            s.params.transitionWidth = transitionWidth;
            s.params.hardDepth = hardDepth;
            s.params.inclusionCentre = inclusionCentre;
            s.params.inclusionRadius = inclusionRadius;
            s.params.fatThickness = fatThickness;
            s.voxelSize = voxelSize;
            s.noiseSigmaHu = noiseSigmaHu;
            s.blurSigma = blurSigma;
            s.supersample = supersample;
            s.seed = seed;
            s.margin = margin;
            py::gil_scoped_release release;
            return std::make_shared<Volume>(volume::makePhantomVolume(s));
        },
        py::arg("scene") = "avc", py::kw_only(), py::arg("voxel_size") = 0.5e-3,
        py::arg("quadrant") = 0, py::arg("shape") = "circle", py::arg("displacement") = 0,
        py::arg("bone_tilt_deg") = 10.0, py::arg("profile") = "linear",
        py::arg("transition_width") = 0.010, py::arg("hard_depth") = 0.015,
        py::arg("inclusion_centre") = Eigen::Vector3d(0, volume::phantom_geometry::kTumourDepth, 0),
        py::arg("inclusion_radius") = volume::phantom_geometry::kTumourRadius,
        py::arg("fat_thickness") = 0.002, py::arg("noise_sigma_hu") = 0.0,
        py::arg("blur_sigma") = 0.0, py::arg("supersample") = 1, py::arg("seed") = 0,
        py::arg("margin") = 0.005,
        "A thesis scene (avc, avcec, bone, stiffness, tumour) as a CT-like volume: surface "
        "at y = 0 facing -y, depth +y, lengths in metres (docs/algorithms.md section 9).");
}

}  // namespace palp::python
