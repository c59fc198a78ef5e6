#pragma once
/// @file
/// A map a clinician can read: a ScalarMap laid out as a figure with axes in millimetres (world
/// LPS coordinates along the map's axes), the patient directions at the ends of each axis (R/L,
/// A/P, S/I), a colour bar in the quantity's units, a title and, optionally, a grey projection
/// of the scan under a semi-transparent heat map (the underlay). The layout (figure size, where
/// the map lies, ticks, labels, bars) is computed once, by layoutMapFigure(), and drawn by two
/// thin back ends: SVG written by hand (map_svg.h: its text stays text) and PNG drawn with cairo
/// (writeMapFigurePng()), so both figures agree pixel for pixel on where things are.

#include <array>
#include <cstdint>
#include <filesystem>
#include <limits>
#include <optional>
#include <string>
#include <vector>

#include "palp/studies/map_png.h"
#include "palp/studies/scalar_map.h"

namespace palp::haptics {

/// A grey picture of the scan under the map: on the map's plane, covering the same rectangle,
/// with pixels as fine as the map's or finer (e.g. a quarter of a 2 mm map pixel).
struct MapUnderlay {
    explicit MapUnderlay(const MapPlane& plane) : map(plane) {}
    ScalarMap map;                        ///< NaN pixels are drawn in the background colour
    std::string quantity = "skin depth";  ///< its bar's label
    /// The map's unit; "mm" whose range stays under 1 mm is labelled and ticked in micrometres.
    std::string units = "mm";
    double lo = std::numeric_limits<double>::quiet_NaN();  ///< NaN: the underlay's min
    double hi = std::numeric_limits<double>::quiet_NaN();  ///< NaN: its max
    /// Small values bright (a depth: near skin white, deep black) instead of large values.
    bool brightLow = false;
};

/// What the figure says around the map.
struct MapFigure {
    std::string title;                   ///< e.g. the scene, mode, source and path
    std::string quantity = "stiffness";  ///< the colour bar's label
    std::string units = "N/m";           ///< the colour bar's units
    ColorMap colorMap = ColorMap::Heat;
    double lo = std::numeric_limits<double>::quiet_NaN();  ///< darkest value; NaN: the map's min
    double hi = std::numeric_limits<double>::quiet_NaN();  ///< brightest value; NaN: its max
    std::optional<MapUnderlay> underlay;                   ///< drawn in grey under the map when set
    double mapOpacity = 0.7;  ///< of the map's pixels over an underlay (0-1]
};

/// The patient direction a world axis points to in LPS: +x "L", -x "R", +y "P", -y "A",
/// +z "S", -z "I" (by the largest component of @p axis).
const char* patientDirection(const Eigen::Vector3d& axis) noexcept;

/// The colour of @p s in [0, 1] (clamped) on @p colorMap: grey levels, or black-red-yellow-white
/// piecewise linear in thirds.
std::array<std::uint8_t, 3> mapColour(double s, ColorMap colorMap) noexcept;

/// A text of the figure; (x, y) is its baseline anchor, px from the top left.
struct FigureText {
    enum class Anchor { Start, Middle, End };
    std::string cls;  ///< title, tick-u, tick-v, axis-u, axis-v, direction, colorbar,
                      ///< colorbar-tick, underlay (the grey bar's label), underlay-tick
    std::string body;
    double x = 0, y = 0;
    double size = 12;  ///< px
    Anchor anchor = Anchor::Start;
    bool bold = false;
    bool vertical = false;  ///< rotated -90 degrees about (x, y) (reads bottom to top)
};

/// A black line of the figure (ticks), px.
struct FigureLine {
    double x1 = 0, y1 = 0, x2 = 0, y2 = 0;
};

/// A vertical colour bar: the colours of @p colorMap from position @p from (0-1) at the bottom
/// (the low value) to @p to at the top (the high value).
struct FigureBar {
    double x = 0, y = 0, w = 0, h = 0;
    ColorMap colorMap = ColorMap::Heat;
    double from = 0, to = 1;
};

/// The grey levels of an underlay span [kUnderlayGreyLo, kUnderlayGreyHi] of black to white, so
/// that white (and black) on a figure always belong to the map's own colours.
inline constexpr double kUnderlayGreyLo = 0.1, kUnderlayGreyHi = 0.65;
/// The colour of an underlay value at @p s in [0, 1] of its range (reversed when @p brightLow).
std::array<std::uint8_t, 3> underlayColour(double s, bool brightLow) noexcept;

/// Where everything of a figure lies, px (y down). Map pixel (col, row-from-bottom) covers
/// [mapX + col cell, mapX + (col + 1) cell] x [mapY + (rows - 1 - row) cell, ... + cell].
struct MapLayout {
    double width = 0, height = 0;
    double mapX = 0, mapY = 0, mapW = 0, mapH = 0;
    double cell = 1;                    ///< px per map pixel
    double underCell = 1;               ///< px per underlay pixel
    double lo = 0, hi = 0;              ///< the map's colour range (NaN when it is empty)
    double underLo = 0, underHi = 0;    ///< the underlay's grey range
    FigureBar bar;                      ///< the map's colour bar
    std::optional<FigureBar> underBar;  ///< the underlay's grey bar
    std::vector<FigureText> texts;
    std::vector<FigureLine> lines;
    /// The world coordinate (mm) along the map's u axis (its positive world axis, e.g. x) at
    /// image x = @p px, and along v at image y = @p py; and back.
    double mmAtX(double px) const noexcept { return u0 + uPerPx * (px - mapX); }
    double mmAtY(double py) const noexcept { return v0 + vPerPx * (mapY + mapH - py); }
    double xAtMm(double mm) const noexcept { return mapX + (mm - u0) / uPerPx; }
    double yAtMm(double mm) const noexcept { return mapY + mapH - (mm - v0) / vPerPx; }
    /// World coordinate (mm) at the map's left (u0) and bottom (v0) edges, mm per px (signed:
    /// negative when u or v points down a world axis).
    double u0 = 0, v0 = 0, uPerPx = 1, vPerPx = 1;
};

/// The layout of @p map drawn as @p figure: square map pixels, the map's longer side about
/// 480 px; ticks every 1, 2 or 5 x 10^k mm labelled with the world coordinate (mm) along each
/// axis; the axes' names ("x (mm)", ...); the patient directions at their ends; the colour bar
/// with ticks and its label "quantity (units)"; the underlay's grey bar when there is one; the
/// title. @p scale multiplies every length (a PNG drawn at 2x is sharper; SVG uses 1).
/// @throw palp::ValueError for a scale outside [0.25, 8] or a map opacity outside (0, 1], or an
///        underlay over another plane.
MapLayout layoutMapFigure(const ScalarMap& map, const MapFigure& figure, double scale = 1);

/// The scale `palp palpate --map FILE.png` draws at (a 480 px map becomes 720 px).
inline constexpr double kMapPngScale = 1.5;

/// Draws @p map as @p figure with cairo at @p scale and writes it as a PNG (RGB) to a
/// temporary file next to @p path, renamed into place.
/// @throw palp::IoError naming the file; palp::ValueError from layoutMapFigure().
void writeMapFigurePng(const std::filesystem::path& path, const ScalarMap& map,
                       const MapFigure& figure = {}, double scale = kMapPngScale);

}  // namespace palp::haptics
