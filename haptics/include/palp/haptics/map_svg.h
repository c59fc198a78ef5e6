#pragma once
/// @file
/// A map a clinician can read: a ScalarMap drawn as an SVG figure with axes in millimetres
/// (world LPS coordinates along the map's axes), the patient directions at the ends of each
/// axis (R/L, A/P, S/I), a colour bar in the quantity's units and a title.

#include <filesystem>
#include <limits>
#include <string>

#include "palp/haptics/map_png.h"
#include "palp/haptics/scalar_map.h"

namespace palp::haptics {

/// What the figure says around the map.
struct MapFigure {
    std::string title;                   ///< e.g. the scene, mode, source and path
    std::string quantity = "stiffness";  ///< the colour bar's label
    std::string units = "N/m";           ///< the colour bar's units
    ColorMap colorMap = ColorMap::Heat;
    double lo = std::numeric_limits<double>::quiet_NaN();  ///< darkest value; NaN: the map's min
    double hi = std::numeric_limits<double>::quiet_NaN();  ///< brightest value; NaN: its max
};

/// The patient direction a world axis points to in LPS: +x "L", -x "R", +y "P", -y "A",
/// +z "S", -z "I" (by the largest component of @p axis).
const char* patientDirection(const Eigen::Vector3d& axis) noexcept;

/// Writes @p map as an SVG figure: one rect per map pixel (its mean as attribute data-v; empty
/// pixels dark blue, no data-v), image right = the plane's u, up = v; ticks every 1, 2 or 5 x
/// 10^k mm labelled with the world coordinate (mm) along each axis (text classes "tick-u",
/// "tick-v", centred on their tick), the axes' names ("x (mm)", ...; classes "axis-u",
/// "axis-v"), the patient directions at the axes' ends (class "direction"), a colour bar with
/// its label "quantity (units)" (class "colorbar") and the title (class "title"). Written to a
/// temporary file next to @p path and renamed into place.
/// @throw palp::IoError naming the file.
void writeMapSvg(const std::filesystem::path& path, const ScalarMap& map,
                 const MapFigure& figure = {});

}  // namespace palp::haptics
