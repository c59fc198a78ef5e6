#pragma once
/// @file
/// Writing a ScalarMap as a PNG image (encoded with libpng, written atomically).

#include <filesystem>
#include <limits>

#include "palp/studies/scalar_map.h"

namespace palp::haptics {

/// Colour scale of a map image: grey levels, or black-red-yellow-white.
enum class ColorMap { Grey, Heat };
/// How writeMapPng() renders a map.
struct PngOptions {
    ColorMap colorMap = ColorMap::Heat;
    double lo = std::numeric_limits<double>::quiet_NaN();  ///< value shown darkest; NaN: min
    double hi = std::numeric_limits<double>::quiet_NaN();  ///< value shown brightest; NaN: max
    int scale = 1;  ///< each map pixel becomes scale x scale image pixels (1-16)
};

/// Writes @p map as an 8-bit PNG (grey, or RGB for Heat: black-red-yellow-white), row 0 at
/// the top = largest v; empty pixels are black (grey) or dark blue (Heat). Written to a
/// temporary file next to @p path and renamed into place.
/// @throw palp::IoError naming the file; palp::ValueError for bad options.
void writeMapPng(const std::filesystem::path& path, const ScalarMap& map,
                 const PngOptions& options = {});

}  // namespace palp::haptics
