// Paths on a scan's skin from Python, as `palp palpate` lays them: the patch of skin that faces
// a press axis (haptics/devices/skin_patch.h) and the skin's height field under a path
// (skin_field.h), which a trajectory's `skin` attribute (devices.cpp) follows. On a deformable
// scene both are measured on the body's surface at rest, the surface its proxy slides on.

#include <pybind11/eigen.h>
#include <pybind11/stl.h>

#include <memory>
#include <optional>
#include <string>

#include "bindings.h"
#include "palp/base/error.h"
#include "palp/haptics/devices/skin_field.h"
#include "palp/haptics/devices/skin_patch.h"
#include "palp/haptics/scene.h"
#include "palp/haptics/tissue/deformable.h"
#include "palp/haptics/tissue/deformable_setup.h"
#include "palp/kernels/embree_scene.h"
#include "palp/volume/volume.h"

namespace palp::python {
namespace {

using haptics::SkinField;
using haptics::SkinPatch;

/// The surfaces a path on @p scene should follow: a deformable body's surface at rest (its
/// proxy's surface), else the scene's iso-surface. @p keep holds the rest surface's scene.
const kernels::EmbreeScene& pathSurfaces(const haptics::Scene& scene,
                                         std::unique_ptr<kernels::EmbreeScene>& keep) {
    const auto& body = scene.deformable();
    if (!body) return scene.surfaces();
    keep = haptics::restSurfaceScene(*body);
    return *keep;
}

/// "+x", "-y", ... as a unit axis. @throw palp::ValueError naming press.
Eigen::Vector3d parseAxis(const std::string& s) {
    static const char* kNames[] = {"+x", "-x", "+y", "-y", "+z", "-z"};
    for (int i = 0; i < 6; ++i) {
        if (s == kNames[i]) return (i % 2 ? -1.0 : 1.0) * Eigen::Vector3d::Unit(i / 2);
    }
    throw ValueError("find_skin_patch press: expected +x, -x, +y, -y, +z or -z, found '" + s + "'");
}

/// The volume's box: its active voxels' centres grown by half a voxel (palp palpate's).
Eigen::AlignedBox3d volumeBox(const volume::Volume& vol) {
    const openvdb::BBoxd box = vol.worldBounds();
    if (box.empty()) throw ValueError("find_skin_patch volume: expected active voxels, found none");
    const double half = 0.5 * vol.voxelSize();
    return {Eigen::Vector3d(box.min().x() - half, box.min().y() - half, box.min().z() - half),
            Eigen::Vector3d(box.max().x() + half, box.max().y() + half, box.max().z() + half)};
}

}  // namespace

void bindSkin(py::module_& m) {
    py::class_<SkinPatch>(m, "SkinPatch",
                          "A rectangle on the plane of a volume's face whose skin faces the "
                          "press axis (find_skin_patch()); world frame, m.")
        .def_readonly("centre", &SkinPatch::centre, "on the face's plane, m")
        .def_readonly("u", &SkinPatch::u, "unit, lateral (the smaller axis index)")
        .def_readonly("v", &SkinPatch::v, "unit, lateral (the larger axis index)")
        .def_readonly("press", &SkinPatch::press, "unit axis, into the body")
        .def_readonly("extent_u", &SkinPatch::extentU, "m")
        .def_readonly("extent_v", &SkinPatch::extentV, "m")
        .def_readonly("facing_fraction", &SkinPatch::facingFraction,
                      "share of the face whose skin faces the press");

    m.def(
        "find_skin_patch",
        [](const haptics::Scene& scene, const volume::Volume& vol,
           std::optional<std::string> press) {
            const Eigen::AlignedBox3d box = volumeBox(vol);
            std::optional<Eigen::Vector3d> axis;
            if (press) axis = parseAxis(*press);
            py::gil_scoped_release release;
            std::unique_ptr<kernels::EmbreeScene> keep;
            const kernels::EmbreeScene& surfaces = pathSurfaces(scene, keep);
            const SkinPatch patch =
                axis ? haptics::findSkinPatch(surfaces, box, *axis)
                     : haptics::findBestSkinPatch(surfaces, box, {}, haptics::kSidePressAxes);
            if (!(patch.extentU > 0 && patch.extentV > 0)) {
                throw ValueError(
                    "find_skin_patch: expected skin facing the press (within 35 degrees) over a "
                    "rectangle more than 10 mm across, found none " +
                    std::string(press ? "on the side " + *press : "on any side across S/I"));
            }
            return patch;
        },
        py::arg("scene"), py::arg("volume"), py::arg("press") = py::none(),
        "The largest rectangle of the face of volume's box against press ('+y', '-x', ...) "
        "whose skin (the scene's proxy surface: a deformable body's at rest) faces the press; "
        "press None: the side across S/I with the most such skin, as palp palpate on a scan. "
        "Raises palp.ValueError when there is none.");

    py::class_<SkinField, std::shared_ptr<SkinField>>(
        m, "SkinField",
        "The skin's height along a press axis over a rectangle of a plane (measured once, "
        "smoothed and slope-limited): a trajectory's `skin` lays its path on it.")
        .def_static(
            "measure",
            [](const haptics::Scene& scene, const Eigen::Vector3d& centre, const Eigen::Vector3d& u,
               const Eigen::Vector3d& v, const Eigen::Vector3d& press, double extentU,
               double extentV, double cell, double startOffset, double rayLength, double smooth,
               double maxSlope) {
                haptics::SkinFieldSpec s;
                s.centre = centre;
                s.u = u;
                s.v = v;
                s.press = press;
                s.extentU = extentU;
                s.extentV = extentV;
                s.cellM = cell;
                s.startOffsetM = startOffset;
                s.rayLengthM = rayLength;
                s.smoothM = smooth;
                s.maxSlope = maxSlope;
                py::gil_scoped_release release;
                std::unique_ptr<kernels::EmbreeScene> keep;
                return std::make_shared<SkinField>(
                    SkinField::measure(pathSurfaces(scene, keep), s));
            },
            py::arg("scene"), py::arg("centre"), py::arg("u"), py::arg("v"), py::arg("press"),
            py::arg("extent_u"), py::arg("extent_v"), py::kw_only(), py::arg("cell") = 1e-3,
            py::arg("start_offset") = 5e-3, py::arg("ray_length") = 0.3, py::arg("smooth") = 2e-3,
            py::arg("max_slope") = 1.0,
            "Casts a ray along press (unit, into the body) per cell of the extent_u x extent_v "
            "rectangle (m) centred on centre, spanned by unit u and v, against the scene's "
            "proxy surface (a deformable body's at rest). Raises palp.ValueError naming the "
            "field, or when no ray finds the skin.")
        .def_property_readonly("hit_fraction", &SkinField::hitFraction,
                               "share of the rays that found the skin")
        .def(
            "height",
            [](const SkinField& f, double a, double b) {
                double h = 0, dhda = 0, dhdb = 0;
                f.sample(a, b, h, dhda, dhdb);
                return h;
            },
            py::arg("a"), py::arg("b"),
            "The skin's depth below the plane along press (m) at lateral (a, b) from centre.");
}

}  // namespace palp::python
