// The error map's figures with cairo (sweep_plots.h): parallel coordinates and per-variable
// scatter / box panels, each drawn once by a function of the cairo context and written as PNG,
// SVG and PDF.
#include "palp/studies/sweep_plots.h"

#include <cairo-pdf.h>
#include <cairo-svg.h>
#include <cairo.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <functional>
#include <memory>
#include <set>

#include "../cairo_pages.h"
#include "palp/base/error.h"

namespace palp::haptics {

namespace plots_impl {

namespace fs = std::filesystem;

using cairo_pages::Align;
using cairo_pages::fmt3;
using cairo_pages::text;
using cairo_pages::writeAll;

/// Blue (0) to red (1) through pale yellow.
void colour(cairo_t* cr, double t, double alpha) {
    t = std::clamp(t, 0.0, 1.0);
    const double r = t < 0.5 ? 0.2 + 1.6 * t * 0.5 : 0.6 + 0.8 * (t - 0.5);
    const double g = t < 0.5 ? 0.35 + 0.8 * t : 0.75 - 1.3 * (t - 0.5);
    const double b = t < 0.5 ? 0.75 - 0.5 * t : 0.5 - 0.8 * (t - 0.5);
    cairo_set_source_rgba(cr, std::clamp(r, 0.0, 1.0), std::clamp(g, 0.0, 1.0),
                          std::clamp(b, 0.0, 1.0), alpha);
}

struct Column {
    std::string label;
    std::vector<double> v;
    double lo = 0, hi = 1;
    bool log = false;
    double pos(double x) const {  // 0 at lo, 1 at hi
        if (hi == lo) return 0.5;
        return log ? (std::log10(x) - std::log10(lo)) / (std::log10(hi) - std::log10(lo))
                   : (x - lo) / (hi - lo);
    }
};

Column makeColumn(const SweepTable& t, int c, const std::vector<Eigen::Index>& rows) {
    Column col;
    const auto& unit = t.units[static_cast<std::size_t>(c)];
    col.label = t.names[static_cast<std::size_t>(c)] + (unit == "1" ? "" : " (" + unit + ")");
    for (auto r : rows) col.v.push_back(t.data(r, c));
    col.lo = *std::min_element(col.v.begin(), col.v.end());
    col.hi = *std::max_element(col.v.begin(), col.v.end());
    col.log = col.lo > 0 && col.hi / col.lo > 50.0;
    return col;
}

/// Axis ticks of a column: lo, hi and, on a log axis, the decades between.
std::vector<double> ticks(const Column& c) {
    std::vector<double> out{c.lo};
    if (c.log) {
        for (double d = std::ceil(std::log10(c.lo)); d <= std::floor(std::log10(c.hi)); d += 1)
            if (std::pow(10.0, d) > c.lo * 1.2 && std::pow(10.0, d) < c.hi / 1.2)
                out.push_back(std::pow(10.0, d));
    } else {
        out.push_back(0.5 * (c.lo + c.hi));
    }
    out.push_back(c.hi);
    return out;
}

std::string tickText(const Column& c, double v) {
    return c.log && v != c.lo && v != c.hi ? "1e" + fmt3(std::log10(v)) : fmt3(v);
}

}  // namespace plots_impl

using namespace plots_impl;

void writeSweepPlots(const SweepTable& table, const std::string& response,
                     const std::vector<PrccEntry>& prcc, const fs::path& dir, int maxLines) {
    const int yc = table.column(response);
    if (yc < 0) throw ValueError("plots: no column '" + response + "'");
    std::vector<Eigen::Index> rows;
    for (Eigen::Index r = 0; r < table.data.rows(); ++r)
        if (std::isfinite(table.data(r, yc))) rows.push_back(r);
    if (rows.empty()) throw ValueError("plots: no row has a finite '" + response + "'");
    std::vector<Column> cols;
    std::vector<double> rs;
    for (const auto& e : prcc) {
        const int c = table.column(e.name);
        if (c < 0) throw ValueError("plots: no column '" + e.name + "'");
        cols.push_back(makeColumn(table, c, rows));
        rs.push_back(e.r);
    }
    Column y = makeColumn(table, yc, rows);
    y.log = y.lo > 0 && y.hi / y.lo > 10.0;
    const std::string yTitle = table.descriptions[static_cast<std::size_t>(yc)];
    const std::size_t n = rows.size();

    // Parallel coordinates: one vertical axis per variable (left to right by |PRCC|), the error
    // last; a line per sample, coloured by the error's position on its axis.
    std::vector<std::size_t> order(cols.size());
    for (std::size_t i = 0; i < order.size(); ++i) order[i] = i;
    std::stable_sort(order.begin(), order.end(), [&](std::size_t a, std::size_t b) {
        return std::abs(rs[a]) > std::abs(rs[b]);
    });
    const double w = 110.0 * static_cast<double>(cols.size() + 1) + 60.0, h = 480.0;
    const double top = 70.0, bottom = h - 95.0;
    const std::size_t stride = std::max<std::size_t>(1, n / static_cast<std::size_t>(maxLines));
    writeAll(dir / "parallel", w, h, [&](cairo_t* cr) {
        text(cr, w / 2, 24,
             "Error map: parallel coordinates of " + std::to_string(n) + " samples (" +
                 std::to_string((n + stride - 1) / stride) + " drawn), colour = " + response,
             14, Align::centre);
        text(cr, w / 2, 44, yTitle, 10, Align::centre);
        auto axisX = [&](std::size_t k) { return 60.0 + 110.0 * static_cast<double>(k) + 30.0; };
        auto axisY = [&](const Column& c, double v) { return bottom - c.pos(v) * (bottom - top); };
        cairo_set_line_width(cr, 0.5);
        for (std::size_t i = 0; i < n; i += stride) {
            colour(cr, y.pos(y.v[i]), 0.35);
            for (std::size_t k = 0; k < order.size(); ++k) {
                const double px = axisX(k), py = axisY(cols[order[k]], cols[order[k]].v[i]);
                if (k == 0)
                    cairo_move_to(cr, px, py);
                else
                    cairo_line_to(cr, px, py);
            }
            cairo_line_to(cr, axisX(order.size()), axisY(y, y.v[i]));
            cairo_stroke(cr);
        }
        for (std::size_t k = 0; k <= order.size(); ++k) {
            const Column& c = k < order.size() ? cols[order[k]] : y;
            const double x = axisX(k);
            cairo_set_source_rgb(cr, 0.1, 0.1, 0.1);
            cairo_set_line_width(cr, 1.2);
            cairo_move_to(cr, x, top);
            cairo_line_to(cr, x, bottom);
            cairo_stroke(cr);
            for (double v : ticks(c)) {
                cairo_move_to(cr, x - 4, axisY(c, v));
                cairo_line_to(cr, x, axisY(c, v));
                cairo_stroke(cr);
                text(cr, x - 6, axisY(c, v) + 3, tickText(c, v), 8, Align::right);
            }
            text(cr, x, bottom + 18, c.label, 9, Align::centre);
            if (k < order.size())
                text(cr, x, bottom + 32, "PRCC " + fmt3(rs[order[k]]), 9, Align::centre);
            else
                text(cr, x, bottom + 32, c.log ? "(log scale)" : "", 9, Align::centre);
        }
        text(cr, 20, h - 20,
             "Axes run from each column's minimum (bottom) to its maximum (top); variables "
             "ordered by |PRCC| with " +
                 response + ".",
             9, Align::left);
    });

    // One panel per variable: the error against it, box plots for at most 8 distinct values.
    const int per = 4;
    const int panelRows = static_cast<int>((cols.size() + per - 1) / per);
    const double pw = 230.0, ph = 200.0;
    const double W = per * pw + 20.0, H = panelRows * ph + 50.0;
    writeAll(dir / "variables", W, H, [&](cairo_t* cr) {
        text(cr, W / 2, 24, response + " against each variable (" + std::to_string(n) + " samples)",
             14, Align::centre);
        for (std::size_t k = 0; k < cols.size(); ++k) {
            const Column& c = cols[k];
            const double x0 = 20.0 + static_cast<double>(k % per) * pw + 45.0;
            const double y0 = 40.0 + static_cast<double>(k / per) * ph + 22.0;
            const double aw = pw - 65.0, ah = ph - 70.0;
            auto X = [&](double v) { return x0 + c.pos(v) * aw; };
            auto Y = [&](double v) { return y0 + ah - y.pos(v) * ah; };
            text(cr, x0 + aw / 2, y0 - 8, c.label + ": PRCC " + fmt3(rs[k]), 9, Align::centre);
            std::set<double> distinct(c.v.begin(), c.v.end());
            if (distinct.size() <= 8) {
                const double bw = std::min(24.0, aw / (2.0 * static_cast<double>(distinct.size())));
                std::size_t slot = 0;
                for (double val : distinct) {
                    std::vector<double> e;
                    for (std::size_t i = 0; i < n; ++i)
                        if (c.v[i] == val) e.push_back(y.v[i]);
                    std::sort(e.begin(), e.end());
                    auto q = [&](double p) {
                        return e[std::min(e.size() - 1, static_cast<std::size_t>(
                                                            p * static_cast<double>(e.size())))];
                    };
                    const double cx = distinct.size() == 1
                                          ? x0 + aw / 2
                                          : x0 + aw * (static_cast<double>(slot) + 0.5) /
                                                     static_cast<double>(distinct.size());
                    cairo_set_source_rgba(cr, 0.3, 0.45, 0.75, 0.35);
                    cairo_rectangle(cr, cx - bw / 2, Y(q(0.75)), bw, Y(q(0.25)) - Y(q(0.75)));
                    cairo_fill_preserve(cr);
                    cairo_set_source_rgb(cr, 0.15, 0.25, 0.5);
                    cairo_set_line_width(cr, 1.0);
                    cairo_stroke(cr);
                    cairo_move_to(cr, cx - bw / 2, Y(q(0.5)));
                    cairo_line_to(cr, cx + bw / 2, Y(q(0.5)));
                    cairo_move_to(cr, cx, Y(q(0.75)));
                    cairo_line_to(cr, cx, Y(q(0.95)));
                    cairo_move_to(cr, cx, Y(q(0.25)));
                    cairo_line_to(cr, cx, Y(q(0.05)));
                    cairo_stroke(cr);
                    text(cr, cx, y0 + ah + 12, fmt3(val), 8, Align::centre);
                    ++slot;
                }
            } else {
                cairo_set_source_rgba(cr, 0.2, 0.3, 0.6, 0.35);
                for (std::size_t i = 0; i < n; i += std::max<std::size_t>(1, n / 3000)) {
                    cairo_arc(cr, X(c.v[i]), Y(y.v[i]), 1.2, 0, 2 * M_PI);
                    cairo_fill(cr);
                }
                for (double v : ticks(c))
                    text(cr, X(v), y0 + ah + 12, tickText(c, v), 8, Align::centre);
            }
            cairo_set_source_rgb(cr, 0.1, 0.1, 0.1);
            cairo_set_line_width(cr, 0.8);
            cairo_rectangle(cr, x0, y0, aw, ah);
            cairo_stroke(cr);
            for (double v : ticks(y)) {
                cairo_move_to(cr, x0 - 3, Y(v));
                cairo_line_to(cr, x0, Y(v));
                cairo_stroke(cr);
                text(cr, x0 - 5, Y(v) + 3, tickText(y, v), 8, Align::right);
            }
            text(cr, x0 + aw / 2, y0 + ah + 26, c.label, 9, Align::centre);
            text(cr, x0 - 33, y0 + ah / 2, response + (y.log ? " (log)" : ""), 9, Align::centre,
                 true);
        }
    });
}

}  // namespace palp::haptics
