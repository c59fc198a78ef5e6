// Studies and maps (the machinery of `palp palpate --map` and of the virtual experiments):
// palp.MapPlane, palp.Map (a ScalarMap as numpy arrays; PNG and figure writers; Otsu's
// threshold), binning a trace (Session.run's numpy columns) into a map, run summaries, the
// underlays (skin depth, MIP), masks' intersection over union, the observers' tie-aware pick and
// trajectory durations.
#include <pybind11/eigen.h>
#include <pybind11/functional.h>
#include <pybind11/numpy.h>
#include <pybind11/stl.h>
#include <pybind11/stl/filesystem.h>

#include <cmath>
#include <filesystem>
#include <optional>
#include <string>
#include <vector>

#include "bindings.h"
#include "palp/base/error.h"
#include "palp/haptics/scene.h"
#include "palp/studies/map_figure.h"
#include "palp/studies/map_png.h"
#include "palp/studies/map_svg.h"
#include "palp/studies/map_underlay.h"
#include "palp/studies/mask.h"
#include "palp/studies/offline_run.h"
#include "palp/studies/scalar_map.h"
#include "palp/volume/volume.h"

namespace palp::python {

using haptics::MapPlane;
using haptics::ScalarMap;
using haptics::Snapshot;

namespace {

haptics::ColorMap parseColorMap(const std::string& name) {
    if (name == "heat") return haptics::ColorMap::Heat;
    if (name == "grey" || name == "gray") return haptics::ColorMap::Grey;
    throw ValueError("color_map: expected 'heat' or 'grey', found '" + name + "'");
}

double orNan(const std::optional<double>& v) { return v.value_or(std::nan("")); }

/// A column of @p trace: an array of @p n rows (n = -1: any) and, for vectors, 3 columns.
py::array_t<double, py::array::c_style | py::array::forcecast> column(const py::dict& trace,
                                                                      const char* name, bool vector,
                                                                      py::ssize_t& n) {
    if (!trace.contains(name)) {
        throw ValueError(std::string("trace: expected a column '") + name +
                         "' (a dict as Session.run returns), found none");
    }
    auto a = py::array_t<double, py::array::c_style | py::array::forcecast>::ensure(trace[name]);
    const bool shapeOk = a && (vector ? a.ndim() == 2 && a.shape(1) == 3 : a.ndim() == 1) &&
                         (n < 0 || a.shape(0) == n);
    if (!shapeOk) {
        std::string found = "not an array of numbers";
        if (a) {
            found = "shape (";
            for (py::ssize_t i = 0; i < a.ndim(); ++i)
                found += (i ? ", " : "") + std::to_string(a.shape(i));
            found += a.ndim() == 1 ? ",)" : ")";
        }
        const std::string rows = n < 0 ? "n" : std::to_string(n);
        throw ValueError(std::string("trace: expected column '") + name + "' of shape (" + rows +
                         (vector ? ", 3)" : ",)") + (n < 0 ? "" : " like 'time'") + ", found " +
                         found);
    }
    n = a.shape(0);
    return a;
}

/// The snapshots of a trace (Session.run's columns; the fields maps and summaries read).
/// @throw palp::ValueError naming a missing or misshapen column.
std::vector<Snapshot> snapshotsOf(const py::dict& trace) {
    py::ssize_t n = -1;
    const auto time = column(trace, "time", false, n);  // sets n: the others are "like 'time'"
    const auto proxy = column(trace, "proxy", true, n);
    const auto probe = column(trace, "probe", true, n);
    const auto force = column(trace, "force", true, n);
    const auto energyForce = column(trace, "energy_force", true, n);
    const auto proxyForce = column(trace, "proxy_force", true, n);
    const auto stiffness = column(trace, "stiffness", false, n);
    const auto rayLength = column(trace, "ray_length", false, n);
    const auto distance = column(trace, "distance", false, n);
    const auto contactCount = column(trace, "contact_count", false, n);
    const auto rays = column(trace, "rays", false, n);
    const auto mode = column(trace, "mode", false, n);
    const auto observerEnergy = column(trace, "observer_energy", false, n);
    const auto faulted = column(trace, "faulted", false, n);
    const auto clamped = column(trace, "clamped", false, n);
    std::vector<Snapshot> out(static_cast<std::size_t>(n));
    const auto v3 = [](const auto& a, py::ssize_t i) {
        return Eigen::Vector3d(a.at(i, 0), a.at(i, 1), a.at(i, 2));
    };
    for (py::ssize_t i = 0; i < n; ++i) {
        Snapshot& s = out[static_cast<std::size_t>(i)];
        s.tick = static_cast<std::uint64_t>(i);
        s.proxy = v3(proxy, i);
        s.probe = v3(probe, i);
        s.force = v3(force, i);
        s.energyForce = v3(energyForce, i);
        s.proxyForce = v3(proxyForce, i);
        s.timeSeconds = time.at(i);
        s.stiffness = stiffness.at(i);
        s.rayLength = rayLength.at(i);
        s.distance = distance.at(i);
        s.contactCount = static_cast<int>(contactCount.at(i));
        s.rays = static_cast<int>(rays.at(i));
        const double m = mode.at(i);
        if (!(m == 0 || m == 1 || m == 2)) {
            throw ValueError(
                "trace: expected column 'mode' of 0 (vc), 1 (avc) or 2 (avcec), "
                "found " +
                std::to_string(m) + " at row " + std::to_string(i));
        }
        s.mode = static_cast<haptics::CouplingMode>(static_cast<int>(m));
        s.observerEnergy = observerEnergy.at(i);
        s.faulted = faulted.at(i) != 0;
        s.clamped = clamped.at(i) != 0;
    }
    return out;
}

/// (rows, cols) array of a map's per-pixel @p get(col, row), row 0 = the bottom row (smallest v).
template <typename T, typename Get>
py::array_t<T> pixels(const ScalarMap& map, Get get) {
    py::array_t<T> a(std::vector<py::ssize_t>{map.rows(), map.cols()});
    auto r = a.template mutable_unchecked<2>();
    for (int row = 0; row < map.rows(); ++row)
        for (int col = 0; col < map.cols(); ++col) r(row, col) = get(col, row);
    return a;
}

/// A mask (rows, cols) as palp's row-major-from-the-bottom vector. @throw palp::ValueError.
haptics::Mask toMask(const py::array& array, const char* name) {
    auto a = py::array_t<std::uint8_t, py::array::c_style | py::array::forcecast>::ensure(array);
    if (!a || a.ndim() != 2) {
        throw ValueError(std::string(name) + ": expected a 2-D mask (rows, cols), found " +
                         (a ? std::to_string(a.ndim()) + " dimensions" : "not an array"));
    }
    haptics::Mask m(static_cast<std::size_t>(a.size()));
    for (std::size_t i = 0; i < m.size(); ++i) m[i] = a.data()[i] ? 1 : 0;
    return m;
}

py::array_t<std::uint8_t> maskArray(const ScalarMap& map, const haptics::Mask& mask) {
    return pixels<std::uint8_t>(map, [&](int col, int row) {
        return mask[static_cast<std::size_t>(row) * static_cast<std::size_t>(map.cols()) +
                    static_cast<std::size_t>(col)];
    });
}

py::dict layoutDict(const haptics::MapLayout& l) {
    py::dict d;
    d["width_px"] = std::ceil(l.width);
    d["height_px"] = std::ceil(l.height);
    d["map_px"] = py::make_tuple(l.mapX, l.mapY, l.mapW, l.mapH);
    d["u_mm"] = py::make_tuple(l.mmAtX(l.mapX), l.mmAtX(l.mapX + l.mapW));
    d["v_mm"] = py::make_tuple(l.mmAtY(l.mapY + l.mapH), l.mmAtY(l.mapY));
    return d;
}

}  // namespace

void bindMaps(py::module_& m) {
    py::class_<MapPlane>(m, "MapPlane",
                         "A rectangle of square pixels in a plane (world LPS, m): columns along "
                         "u, rows along v; the default u = +x, v = +z shows the phantoms' skin "
                         "(y = 0) as seen from the anterior side.")
        .def(py::init(&fromKwargs<MapPlane>))
        .def_readwrite("centre", &MapPlane::centre, "m")
        .def_readwrite("u", &MapPlane::u, "unit")
        .def_readwrite("v", &MapPlane::v, "unit, perpendicular to u")
        .def_readwrite("extent_u", &MapPlane::extentU, "m")
        .def_readwrite("extent_v", &MapPlane::extentV, "m")
        .def_readwrite("pixel", &MapPlane::pixelM, "pixel edge, m")
        .def_property_readonly("cols", &MapPlane::cols)
        .def_property_readonly("rows", &MapPlane::rows)
        .def("validate", &haptics::validateMapPlane,
             "Raises palp.ValueError naming the field (extents, pixel, u and v unit and "
             "perpendicular, at most 4096 pixels a side).")
        .def(
            "pixel_centres",
            [](const MapPlane& p) {
                haptics::validateMapPlane(p);
                py::array_t<double> a(std::vector<py::ssize_t>{p.rows(), p.cols(), 3});
                auto r = a.mutable_unchecked<3>();
                for (int row = 0; row < p.rows(); ++row)
                    for (int col = 0; col < p.cols(); ++col) {
                        const Eigen::Vector3d c = p.pixelCentre(col, row);
                        for (int k = 0; k < 3; ++k) r(row, col, k) = c[k];
                    }
                return a;
            },
            "World centres of the pixels, (rows, cols, 3) m, row 0 the bottom row (smallest v): "
            "masks and truths in numpy over the same pixels as Map.values.")
        .def(
            "pixel_of",
            [](const MapPlane& p, const Eigen::Vector3d& world) -> py::object {
                int col = 0, row = 0;
                if (!p.pixelOf(world, col, row)) return py::none();
                return py::make_tuple(row, col);
            },
            py::arg("world"), "(row, col) of the pixel under a world point; None outside.")
        .def("__repr__", [](const MapPlane& p) {
            return "<palp.MapPlane " + std::to_string(p.cols()) + " x " + std::to_string(p.rows()) +
                   " pixels of " + std::to_string(p.pixelM * 1e3) + " mm>";
        });

    py::class_<ScalarMap>(m, "Map",
                          "The mean of a quantity per pixel of a MapPlane (palp palpate --map's "
                          "map). values and counts are (rows, cols) numpy arrays, row 0 the "
                          "bottom row (smallest v): matplotlib's imshow(values, origin='lower').")
        .def(py::init([](const MapPlane& plane, std::optional<py::array_t<double>> values) {
                 ScalarMap map(plane);
                 if (values) {
                     const auto v = values->unchecked();
                     if (v.ndim() != 2 || v.shape(0) != map.rows() || v.shape(1) != map.cols()) {
                         throw ValueError(
                             "Map: expected values of shape (" + std::to_string(map.rows()) + ", " +
                             std::to_string(map.cols()) + ") (the plane's rows, cols)");
                     }
                     for (int row = 0; row < map.rows(); ++row)
                         for (int col = 0; col < map.cols(); ++col) {
                             const double x = v(row, col);
                             if (std::isfinite(x)) map.set(col, row, x);
                         }
                 }
                 return map;
             }),
             py::arg("plane"), py::arg("values") = py::none(),
             "An empty map over plane, or one holding values (rows, cols; NaN: no sample).")
        .def_property_readonly("plane", &ScalarMap::plane)
        .def_property_readonly("cols", &ScalarMap::cols)
        .def_property_readonly("rows", &ScalarMap::rows)
        .def_property_readonly(
            "values",
            [](const ScalarMap& map) {
                return pixels<double>(map, [&](int c, int r) { return map.at(c, r); });
            },
            "Mean per pixel, (rows, cols) float64, NaN where no sample fell (a copy).")
        .def_property_readonly(
            "counts",
            [](const ScalarMap& map) {
                return pixels<std::uint32_t>(map, [&](int c, int r) { return map.count(c, r); });
            },
            "Samples per pixel, (rows, cols) uint32 (filled gaps count 1).")
        .def_property_readonly(
            "range",
            [](const ScalarMap& map) {
                double lo = 0, hi = 0;
                map.range(lo, hi);
                return py::make_tuple(lo, hi);
            },
            "(smallest, largest) finite mean; (nan, nan) when empty.")
        .def("fill_gaps", &ScalarMap::fillGaps, py::arg("passes") = 2,
             "Fills empty pixels with the mean of their filled 8-neighbours, passes times "
             "(closes the gaps between raster lines coarser than the pixels), in place.")
        .def("otsu_threshold", &haptics::otsuThreshold,
             "Otsu's threshold of the finite values (nan with fewer than two distinct).")
        .def(
            "threshold",
            [](const ScalarMap& map, double t) {
                return maskArray(map, haptics::thresholdMap(map, t));
            },
            py::arg("threshold"), "Mask (rows, cols) uint8: 1 where the value >= threshold.")
        .def(
            "write_png",
            [](const ScalarMap& map, const std::filesystem::path& path, const std::string& colorMap,
               std::optional<double> lo, std::optional<double> hi, int scale) {
                haptics::PngOptions o;
                o.colorMap = parseColorMap(colorMap);
                o.lo = orNan(lo);
                o.hi = orNan(hi);
                o.scale = scale;
                py::gil_scoped_release release;
                haptics::writeMapPng(path, map, o);
            },
            py::arg("path"), py::kw_only(), py::arg("color_map") = "heat",
            py::arg("lo") = py::none(), py::arg("hi") = py::none(), py::arg("scale") = 1,
            "The bare map as a PNG (heat or grey), one pixel per map pixel times scale.")
        .def(
            "write_figure",
            [](const ScalarMap& map, const std::filesystem::path& path, const std::string& title,
               const std::string& quantity, const std::string& units, const std::string& colorMap,
               std::optional<double> lo, std::optional<double> hi, const ScalarMap* underlay,
               const std::string& underlayQuantity, const std::string& underlayUnits,
               bool brightLow, double opacity) {
                haptics::MapFigure fig;
                fig.title = title;
                fig.quantity = quantity;
                fig.units = units;
                fig.colorMap = parseColorMap(colorMap);
                fig.lo = orNan(lo);
                fig.hi = orNan(hi);
                fig.mapOpacity = opacity;
                if (underlay) {
                    haptics::MapUnderlay u(underlay->plane());
                    u.map = *underlay;
                    u.quantity = underlayQuantity;
                    u.units = underlayUnits;
                    u.brightLow = brightLow;
                    fig.underlay = u;
                }
                const bool svg = path.extension() == ".svg";
                haptics::MapLayout layout;
                {
                    py::gil_scoped_release release;
                    if (svg) {
                        haptics::writeMapSvg(path, map, fig);
                        layout = haptics::layoutMapFigure(map, fig, 1.0);
                    } else {
                        haptics::writeMapFigurePng(path, map, fig, haptics::kMapPngScale);
                        layout = haptics::layoutMapFigure(map, fig, haptics::kMapPngScale);
                    }
                }
                return layoutDict(layout);
            },
            py::arg("path"), py::kw_only(), py::arg("title") = "",
            py::arg("quantity") = "stiffness", py::arg("units") = "N/m",
            py::arg("color_map") = "heat", py::arg("lo") = py::none(), py::arg("hi") = py::none(),
            py::arg("underlay") = nullptr, py::arg("underlay_quantity") = "skin depth",
            py::arg("underlay_units") = "mm", py::arg("bright_low") = false,
            py::arg("opacity") = 0.7,
            "The figure of palp palpate --map (.png drawn with cairo, .svg by hand): axes in "
            "world mm, patient directions, colour bar, title, optionally a grey underlay map "
            "(skin_depth_map, mip_map) under it. Returns where the map lies in the image: "
            "{'width_px', 'height_px', 'map_px': (x, y, w, h), 'u_mm', 'v_mm'}.")
        .def("__repr__", [](const ScalarMap& map) {
            double lo = 0, hi = 0;
            map.range(lo, hi);
            return "<palp.Map " + std::to_string(map.cols()) + " x " + std::to_string(map.rows()) +
                   ", " + std::to_string(lo) + " .. " + std::to_string(hi) + ">";
        });

    m.def(
        "bin_trace",
        [](const py::dict& trace, const MapPlane& plane, const std::string& quantity,
           bool contactOnly, const std::string& anchor) {
            const haptics::MapQuantity q = haptics::parseMapQuantity(quantity);
            const haptics::MapAnchor a = haptics::parseMapAnchor(anchor);
            const std::vector<Snapshot> snaps = snapshotsOf(trace);
            py::gil_scoped_release release;
            return haptics::binSnapshots(snaps, plane, q, contactOnly, a);
        },
        py::arg("trace"), py::arg("plane"), py::kw_only(), py::arg("quantity") = "stiffness",
        py::arg("contact_only") = true, py::arg("anchor") = "proxy",
        "A Map of a trace (Session.run's dict, or slices of it): the mean of quantity "
        "('stiffness' N/m, 'force' N, 'energy' N) per pixel where the snapshot lands (anchor "
        "'proxy', or 'ray-end': where the structure that set k lies). contact_only: only ticks "
        "pressing a surface with a ray (palp palpate --map's).");

    m.def(
        "summarize",
        [](const py::dict& trace) {
            const std::vector<Snapshot> snaps = snapshotsOf(trace);
            const haptics::RunSummary r = haptics::summarize(snaps);
            py::dict d;
            d["ticks"] = r.ticks;
            d["seconds"] = r.seconds;
            d["max_force"] = r.maxForceN;
            d["final_observer_energy"] = r.finalObserverEnergy;
            d["min_observer_energy"] = r.minObserverEnergy;
            d["mean_rays"] = r.meanRays;
            d["max_rays"] = r.maxRays;
            d["contact_fraction"] = r.contactFraction;
            d["min_stiffness"] = r.minStiffness;
            d["max_stiffness"] = r.maxStiffness;
            d["faulted_ticks"] = r.faultedTicks;
            d["clamped_ticks"] = r.clampedTicks;
            return d;
        },
        py::arg("trace"),
        "Figures of a run (palp palpate's summary): ticks, seconds, max_force (N), observer "
        "energy (final, min; J), rays (mean, max), contact_fraction, stiffness over contact "
        "ticks (min, max; N/m), faulted and clamped ticks.");

    m.def(
        "skin_depth_map",
        [](const haptics::Scene& scene, const MapPlane& plane, const Eigen::Vector3d& press,
           double length) {
            py::gil_scoped_release release;
            return haptics::skinDepthMap(scene.surfaces(), plane, press, length);
        },
        py::arg("scene"), py::arg("plane"), py::arg("press"), py::arg("length"),
        "Underlay: the skin's depth (mm) along press (unit, into the body) below each pixel of "
        "plane, within length (m); NaN where no skin is.");
    m.def(
        "mip_map",
        [](const volume::Volume& vol, const MapPlane& plane, const Eigen::Vector3d& press,
           double length, const ScalarMap* from) {
            py::gil_scoped_release release;
            return haptics::mipMap(vol, plane, press, length, from);
        },
        py::arg("volume"), py::arg("plane"), py::arg("press"), py::arg("length"),
        py::arg("from_mm") = nullptr,
        "Underlay: the volume's maximum (its units) along press over length (m) from each "
        "pixel (or, with from_mm, e.g. a skin_depth_map, from that far along the press).");

    m.def(
        "intersection_over_union",
        [](const py::array& a, const py::array& b) {
            return haptics::intersectionOverUnion(toMask(a, "a"), toMask(b, "b"));
        },
        py::arg("a"), py::arg("b"), "|a and b| / |a or b| of two masks (1 when both are empty).");
    m.def(
        "pick_largest",
        [](const std::vector<double>& scores, double tolerance, std::uint64_t seed) {
            return haptics::pickLargest(scores, tolerance, seed);
        },
        py::arg("scores"), py::arg("relative_tolerance"), py::arg("seed"),
        "The virtual experiments' observer: the index of the largest score; scores within "
        "relative_tolerance of it are tied and one is chosen by a generator seeded with seed "
        "(never by position); -1 when all are NaN.");
    m.def(
        "trajectory_duration",
        [](const haptics::Trajectory& t, int passes) {
            return haptics::trajectoryDuration(t, passes);
        },
        py::arg("trajectory"), py::arg("passes") = 1,
        "Seconds after which a trajectory has done what it scripts (approach plus passes for "
        "a sweep or circle, the raster's duration, press + hold + return for a press).");
}

}  // namespace palp::python
