// The cairo plumbing the figures share (cairo_pages.h).
#include "cairo_pages.h"

#include <cairo-pdf.h>
#include <cairo-svg.h>

#include <cmath>
#include <cstdio>
#include <memory>

#include "palp/base/atomic_file.h"
#include "palp/base/error.h"

namespace palp::haptics::cairo_pages {

struct SurfaceFree {
    void operator()(cairo_surface_t* s) const noexcept { cairo_surface_destroy(s); }
};
struct ContextFree {
    void operator()(cairo_t* c) const noexcept { cairo_destroy(c); }
};
using Surface = std::unique_ptr<cairo_surface_t, SurfaceFree>;
using Context = std::unique_ptr<cairo_t, ContextFree>;

void check(cairo_status_t s, const std::filesystem::path& p) {
    if (s != CAIRO_STATUS_SUCCESS)
        throw IoError(p.string() + ": cairo cannot write the figure: " + cairo_status_to_string(s));
}

void writeAll(const std::filesystem::path& stem, double w, double h, const Draw& draw) {
    for (const char* ext : {".png", ".svg", ".pdf"}) {
        std::filesystem::path path = stem;
        path.replace_extension(ext);
        AtomicFile f(path, "figure");
        const std::string tmp = f.tempPath().string();
        Surface s;
        const std::string e = ext;
        if (e == ".png")
            s.reset(cairo_image_surface_create(CAIRO_FORMAT_ARGB32, static_cast<int>(2 * w),
                                               static_cast<int>(2 * h)));
        else if (e == ".svg")
            s.reset(cairo_svg_surface_create(tmp.c_str(), w, h));
        else
            s.reset(cairo_pdf_surface_create(tmp.c_str(), w, h));
        check(cairo_surface_status(s.get()), path);
        {
            Context cr(cairo_create(s.get()));
            if (e == ".png") cairo_scale(cr.get(), 2.0, 2.0);
            cairo_set_source_rgb(cr.get(), 1, 1, 1);
            cairo_paint(cr.get());
            draw(cr.get());
            check(cairo_status(cr.get()), path);
        }
        if (e == ".png") check(cairo_surface_write_to_png(s.get(), tmp.c_str()), path);
        cairo_surface_finish(s.get());
        check(cairo_surface_status(s.get()), path);
        s.reset();
        f.commit();
    }
}

void text(cairo_t* cr, double x, double y, const std::string& s, double size, Align a,
          bool vertical) {
    cairo_save(cr);
    cairo_select_font_face(cr, "sans-serif", CAIRO_FONT_SLANT_NORMAL, CAIRO_FONT_WEIGHT_NORMAL);
    cairo_set_font_size(cr, size);
    cairo_text_extents_t ext;
    cairo_text_extents(cr, s.c_str(), &ext);
    cairo_translate(cr, x, y);
    if (vertical) cairo_rotate(cr, -M_PI / 2);
    const double dx = a == Align::left ? 0 : a == Align::centre ? -ext.width / 2 : -ext.width;
    cairo_move_to(cr, dx - ext.x_bearing, 0);
    cairo_set_source_rgb(cr, 0.1, 0.1, 0.1);
    cairo_show_text(cr, s.c_str());
    cairo_restore(cr);
}

std::string fmt3(double v) {
    char buf[32];
    std::snprintf(buf, sizeof buf, "%.3g", v);
    return buf;
}

}  // namespace palp::haptics::cairo_pages
