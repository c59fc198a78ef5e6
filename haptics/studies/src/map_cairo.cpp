// The PNG back end of map figures: the layout of layoutMapFigure() drawn with cairo.
#include <cairo.h>

#include <cmath>
#include <cstdint>
#include <memory>
#include <numbers>
#include <string>

#include "map_util.h"
#include "palp/base/atomic_file.h"
#include "palp/base/error.h"
#include "palp/studies/map_figure.h"

namespace palp::haptics {

namespace {

struct SurfaceFree {
    void operator()(cairo_surface_t* s) const noexcept { cairo_surface_destroy(s); }
};
struct ContextFree {
    void operator()(cairo_t* c) const noexcept { cairo_destroy(c); }
};
struct PatternFree {
    void operator()(cairo_pattern_t* p) const noexcept { cairo_pattern_destroy(p); }
};
using Surface = std::unique_ptr<cairo_surface_t, SurfaceFree>;
using Context = std::unique_ptr<cairo_t, ContextFree>;
using Pattern = std::unique_ptr<cairo_pattern_t, PatternFree>;

constexpr std::uint32_t kEmpty = 0xff000040;  // dark blue, opaque (ARGB)

/// An ARGB32 image of one map pixel per image pixel, row 0 = the largest v; @p colour gives a
/// pixel's premultiplied ARGB from its value.
template <class Colour>
Surface pixelImage(const ScalarMap& map, Colour colour) {
    const int cols = map.cols(), rows = map.rows();
    Surface img(cairo_image_surface_create(CAIRO_FORMAT_ARGB32, cols, rows));
    if (cairo_surface_status(img.get()) != CAIRO_STATUS_SUCCESS) return img;
    cairo_surface_flush(img.get());
    unsigned char* data = cairo_image_surface_get_data(img.get());
    const int stride = cairo_image_surface_get_stride(img.get());
    for (int y = 0; y < rows; ++y) {
        auto* line =
            reinterpret_cast<std::uint32_t*>(data + static_cast<std::ptrdiff_t>(y) * stride);
        for (int x = 0; x < cols; ++x) line[x] = colour(map.at(x, rows - 1 - y));
    }
    cairo_surface_mark_dirty(img.get());
    return img;
}

std::uint32_t argb(const std::array<std::uint8_t, 3>& c) {
    return 0xff000000u | (std::uint32_t{c[0]} << 16) | (std::uint32_t{c[1]} << 8) | c[2];
}

/// Paints @p img over the map's rectangle, each image pixel a square of @p cell px.
void paintPixels(cairo_t* cr, const MapLayout& l, double cell, cairo_surface_t* img, double alpha) {
    cairo_save(cr);
    cairo_rectangle(cr, l.mapX, l.mapY, l.mapW, l.mapH);
    cairo_clip(cr);
    cairo_translate(cr, l.mapX, l.mapY);
    cairo_scale(cr, cell, cell);
    cairo_set_source_surface(cr, img, 0, 0);
    cairo_pattern_set_filter(cairo_get_source(cr), CAIRO_FILTER_NEAREST);
    cairo_paint_with_alpha(cr, alpha);
    cairo_restore(cr);
}

void drawBar(cairo_t* cr, const FigureBar& b, double lineWidth) {
    Pattern g(cairo_pattern_create_linear(0, b.y + b.h, 0, b.y));
    for (int k = 0; k <= 16; ++k) {
        const double f = k / 16.0;
        const auto c = mapColour(b.from + (b.to - b.from) * f, b.colorMap);
        cairo_pattern_add_color_stop_rgb(g.get(), f, c[0] / 255.0, c[1] / 255.0, c[2] / 255.0);
    }
    cairo_rectangle(cr, b.x, b.y, b.w, b.h);
    cairo_set_source(cr, g.get());
    cairo_fill_preserve(cr);
    cairo_set_source_rgb(cr, 0, 0, 0);
    cairo_set_line_width(cr, lineWidth);
    cairo_stroke(cr);
}

void drawText(cairo_t* cr, const FigureText& t) {
    cairo_select_font_face(cr, "DejaVu Sans", CAIRO_FONT_SLANT_NORMAL,
                           t.bold ? CAIRO_FONT_WEIGHT_BOLD : CAIRO_FONT_WEIGHT_NORMAL);
    cairo_set_font_size(cr, t.size);
    cairo_text_extents_t e{};
    cairo_text_extents(cr, t.body.c_str(), &e);
    double dx = 0;
    if (t.anchor == FigureText::Anchor::Middle) dx = -e.x_advance / 2;
    if (t.anchor == FigureText::Anchor::End) dx = -e.x_advance;
    cairo_save(cr);
    cairo_translate(cr, t.x, t.y);
    if (t.vertical) cairo_rotate(cr, -std::numbers::pi / 2);
    cairo_move_to(cr, dx, 0);
    cairo_set_source_rgb(cr, 0, 0, 0);
    cairo_show_text(cr, t.body.c_str());
    cairo_restore(cr);
}

cairo_status_t appendBytes(void* closure, const unsigned char* data, unsigned int length) {
    static_cast<std::string*>(closure)->append(reinterpret_cast<const char*>(data), length);
    return CAIRO_STATUS_SUCCESS;
}

}  // namespace

void writeMapFigurePng(const std::filesystem::path& path, const ScalarMap& map,
                       const MapFigure& figure, double scale) {
    const MapLayout l = layoutMapFigure(map, figure, scale);
    const int width = static_cast<int>(std::ceil(l.width));
    const int height = static_cast<int>(std::ceil(l.height));
    const auto failed = [&](cairo_status_t status) {
        return IoError(path.string() + ": expected to draw a " + std::to_string(width) + "x" +
                       std::to_string(height) +
                       " map figure, cairo failed: " + cairo_status_to_string(status));
    };
    Surface surface(cairo_image_surface_create(CAIRO_FORMAT_RGB24, width, height));
    if (cairo_surface_status(surface.get()) != CAIRO_STATUS_SUCCESS)
        throw failed(cairo_surface_status(surface.get()));
    Context cr(cairo_create(surface.get()));
    cairo_t* c = cr.get();
    cairo_set_source_rgb(c, 1, 1, 1);
    cairo_paint(c);

    // The underlay in grey, then the map (semi-transparent over an underlay; its empty pixels
    // let the underlay show).
    const bool under = figure.underlay.has_value();
    if (under) {
        const MapUnderlay& u = *figure.underlay;
        Surface img = pixelImage(u.map, [&](double v) {
            if (!std::isfinite(v)) return kEmpty;
            const double g = unit(v, l.underLo, l.underHi);
            return argb(underlayColour(g, u.brightLow));
        });
        if (cairo_surface_status(img.get()) != CAIRO_STATUS_SUCCESS)
            throw failed(cairo_surface_status(img.get()));
        paintPixels(c, l, l.underCell, img.get(), 1.0);
    }
    Surface img = pixelImage(map, [&](double v) -> std::uint32_t {
        if (!std::isfinite(v)) return under ? 0u : kEmpty;  // transparent over an underlay
        return argb(mapColour(unit(v, l.lo, l.hi), figure.colorMap));
    });
    if (cairo_surface_status(img.get()) != CAIRO_STATUS_SUCCESS)
        throw failed(cairo_surface_status(img.get()));
    paintPixels(c, l, l.cell, img.get(), under ? figure.mapOpacity : 1.0);

    const double lw = std::max(1.0, scale);
    cairo_set_source_rgb(c, 0, 0, 0);
    cairo_set_line_width(c, lw);
    cairo_rectangle(c, l.mapX, l.mapY, l.mapW, l.mapH);
    cairo_stroke(c);
    drawBar(c, l.bar, lw);
    if (l.underBar) drawBar(c, *l.underBar, lw);
    cairo_set_source_rgb(c, 0, 0, 0);
    cairo_set_line_width(c, lw);
    for (const FigureLine& ln : l.lines) {
        cairo_move_to(c, ln.x1, ln.y1);
        cairo_line_to(c, ln.x2, ln.y2);
    }
    cairo_stroke(c);
    for (const FigureText& t : l.texts) drawText(c, t);
    if (cairo_status(c) != CAIRO_STATUS_SUCCESS) throw failed(cairo_status(c));
    cairo_surface_flush(surface.get());

    std::string bytes;
    const cairo_status_t st = cairo_surface_write_to_png_stream(surface.get(), appendBytes, &bytes);
    if (st != CAIRO_STATUS_SUCCESS) throw failed(st);
    palp::writeFileAtomically(path, "map PNG", bytes.data(), bytes.size());
}

}  // namespace palp::haptics
