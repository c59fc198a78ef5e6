#pragma once
// Internal to palp_studies: the cairo plumbing the figures share (the error map's plots, the
// psychometric plots): one drawing written as PNG, SVG and PDF, and text placed by an anchor.

#include <cairo.h>

#include <filesystem>
#include <functional>
#include <string>

namespace palp::haptics::cairo_pages {

using Draw = std::function<void(cairo_t*)>;

/// Draws @p draw on a @p w x @p h point page and writes it as @p stem .png (2 px a point),
/// .svg and .pdf, each atomically. @throw palp::IoError naming the file cairo cannot write.
void writeAll(const std::filesystem::path& stem, double w, double h, const Draw& draw);

enum class Align { left, centre, right };

/// @p s at (@p x, @p y) (its baseline), @p size points, dark grey; rotated to read upwards when
/// @p vertical.
void text(cairo_t* cr, double x, double y, const std::string& s, double size, Align a,
          bool vertical = false);

/// "%.3g".
std::string fmt3(double v);

}  // namespace palp::haptics::cairo_pages
