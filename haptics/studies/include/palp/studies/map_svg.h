#pragma once
/// @file
/// A map a clinician can read, as an SVG figure written by hand from the shared layout
/// (map_figure.h), so that its labels stay text elements a reader (or a test) can find.

#include <filesystem>

#include "palp/studies/map_figure.h"
#include "palp/studies/scalar_map.h"

namespace palp::haptics {

/// Writes @p map as an SVG figure laid out by layoutMapFigure() at scale 1 (SVG user units =
/// px): one rect per map pixel (its mean as attribute data-v; empty pixels dark blue without
/// data-v, or left out over an underlay), image right = the plane's u, up = v; under it, when
/// figure.underlay is set, a group "underlay" of grey rects (data-u: the underlay's value) and
/// the map's group at figure.mapOpacity. Every text of the layout is a text element with its
/// class (tick labels "tick-u", "tick-v" centred on their tick; "axis-u", "axis-v",
/// "direction", "colorbar", "colorbar-tick", "underlay", "underlay-tick", "title"). Written to a
/// temporary file next to @p path and renamed into place.
/// @throw palp::IoError naming the file; palp::ValueError from layoutMapFigure().
void writeMapSvg(const std::filesystem::path& path, const ScalarMap& map,
                 const MapFigure& figure = {});

}  // namespace palp::haptics
