// The psychometric plot (psychometric_plot.h), drawn once per page by cairo_pages::writeAll.
#include "palp/studies/psychometric_plot.h"

#include <algorithm>
#include <cmath>

#include "../cairo_pages.h"
#include "palp/base/error.h"
#include "palp/perception/psychometric.h"

namespace palp::haptics {

namespace {

using cairo_pages::Align;
using cairo_pages::fmt3;
using cairo_pages::text;

constexpr double kPanelW = 330, kPanelH = 270;
constexpr double kLeft = 58, kRight = 14, kTop = 46, kBottom = 48;
constexpr double kYLo = 0.0, kYHi = 1.0;  // the whole range: blocks of few trials fall below 0.5

double niceStep(double span) {
    const double raw = span / 5;
    const double p = std::pow(10.0, std::floor(std::log10(raw)));
    for (double m : {1.0, 2.0, 5.0})
        if (m * p >= raw) return m * p;
    return 10 * p;
}

struct Frame {
    double x0, y0, w, h, xMax;
    double px(double level) const { return x0 + w * level / xMax; }
    double py(double p) const { return y0 + h - h * (p - kYLo) / (kYHi - kYLo); }
};

void panel(cairo_t* cr, const ConditionResult& r, double ox, double coverage) {
    double xMax = 1;
    for (const auto& b : r.blocks) xMax = std::max(xMax, b.level);
    if (std::isfinite(r.fitInterval.hi)) xMax = std::max(xMax, r.fitInterval.hi);
    xMax *= 1.1;
    const double step = niceStep(xMax);
    xMax = std::ceil(xMax / step) * step;
    const Frame f{ox + kLeft, kTop, kPanelW - kLeft - kRight, kPanelH - kTop - kBottom, xMax};

    // Band, then curve, then data on top.
    cairo_set_line_width(cr, 1);
    constexpr std::size_t n = 160;
    const auto at = [&](std::size_t i) {
        return xMax * (static_cast<double>(i) + 0.5) / static_cast<double>(n + 1);
    };
    if (r.fit && r.bootstrapFits.size() >= 2) {
        std::vector<double> lo(n + 1), hi(n + 1);
        for (std::size_t i = 0; i <= n; ++i) {
            const double x = at(i);
            std::vector<double> v;
            v.reserve(r.bootstrapFits.size());
            for (const auto& b : r.bootstrapFits) v.push_back(perception::psi(b.function, x));
            lo[i] = perception::sampleQuantile(v, (1 - coverage) / 2);
            hi[i] = perception::sampleQuantile(v, (1 + coverage) / 2);
        }
        cairo_new_path(cr);
        for (std::size_t i = 0; i <= n; ++i)
            cairo_line_to(cr, f.px(at(i)), f.py(std::max(kYLo, hi[i])));
        for (std::size_t i = n + 1; i-- > 0;)
            cairo_line_to(cr, f.px(at(i)), f.py(std::max(kYLo, lo[i])));
        cairo_close_path(cr);
        cairo_set_source_rgba(cr, 0.25, 0.45, 0.85, 0.22);
        cairo_fill(cr);
    }
    if (r.fit) {
        cairo_new_path(cr);
        for (std::size_t i = 0; i <= n; ++i) {
            const double x = at(i);
            cairo_line_to(cr, f.px(x), f.py(std::max(kYLo, perception::psi(r.fit->function, x))));
        }
        cairo_set_source_rgb(cr, 0.1, 0.3, 0.75);
        cairo_set_line_width(cr, 2);
        cairo_stroke(cr);
    }
    // Threshold at the target: dashed guides, the interval as a bar.
    if (std::isfinite(r.fitThreshold)) {
        const double dash[] = {4, 3};
        cairo_set_dash(cr, dash, 2, 0);
        cairo_set_line_width(cr, 1);
        cairo_set_source_rgb(cr, 0.75, 0.15, 0.1);
        cairo_move_to(cr, f.px(0), f.py(r.target));
        cairo_line_to(cr, f.px(r.fitThreshold), f.py(r.target));
        cairo_line_to(cr, f.px(r.fitThreshold), f.py(kYLo));
        cairo_stroke(cr);
        cairo_set_dash(cr, nullptr, 0, 0);
        if (std::isfinite(r.fitInterval.lo) && std::isfinite(r.fitInterval.hi)) {
            cairo_set_line_width(cr, 3);
            cairo_move_to(cr, f.px(r.fitInterval.lo), f.py(r.target));
            cairo_line_to(cr, f.px(std::min(r.fitInterval.hi, xMax)), f.py(r.target));
            cairo_stroke(cr);
        }
    }
    // The staircase's threshold: a triangle on the level axis.
    if (std::isfinite(r.procedureThreshold) && r.procedureThreshold <= xMax) {
        const double x = f.px(r.procedureThreshold), y = f.py(kYLo);
        cairo_move_to(cr, x, y - 9);
        cairo_line_to(cr, x - 5, y);
        cairo_line_to(cr, x + 5, y);
        cairo_close_path(cr);
        cairo_set_source_rgb(cr, 0.2, 0.6, 0.25);
        cairo_fill(cr);
    }
    for (const auto& b : r.blocks) {
        const double p = static_cast<double>(b.correct) / b.trials;
        cairo_new_path(cr);
        cairo_arc(cr, f.px(b.level), f.py(std::max(kYLo, p)), 1.5 + 1.6 * std::sqrt(b.trials), 0,
                  2 * M_PI);
        cairo_set_source_rgba(cr, 0.15, 0.15, 0.15, 0.55);
        cairo_fill_preserve(cr);
        cairo_set_source_rgb(cr, 0.1, 0.1, 0.1);
        cairo_set_line_width(cr, 0.8);
        cairo_stroke(cr);
    }

    // Axes, ticks, labels.
    cairo_set_source_rgb(cr, 0.1, 0.1, 0.1);
    cairo_set_line_width(cr, 1);
    cairo_rectangle(cr, f.x0, f.y0, f.w, f.h);
    cairo_stroke(cr);
    for (double t = 0; t <= xMax + 1e-9; t += step) {
        cairo_move_to(cr, f.px(t), f.y0 + f.h);
        cairo_line_to(cr, f.px(t), f.y0 + f.h + 4);
        cairo_stroke(cr);
        text(cr, f.px(t), f.y0 + f.h + 16, fmt3(t), 10, Align::centre);
    }
    for (double p = kYLo; p <= kYHi + 1e-9; p += 0.1) {
        cairo_move_to(cr, f.x0 - 4, f.py(p));
        cairo_line_to(cr, f.x0, f.py(p));
        cairo_stroke(cr);
        text(cr, f.x0 - 7, f.py(p) + 3.5, fmt3(p), 10, Align::right);
    }
    text(cr, f.x0 + f.w / 2, f.y0 + f.h + 34, "comparison increment (% of reference stiffness)",
         10.5, Align::centre);
    text(cr, ox + 16, f.y0 + f.h / 2, "proportion correct", 10.5, Align::centre, true);
    std::string head = r.name + ": " + std::to_string(r.trials) + " trials";
    text(cr, f.x0 + f.w / 2, 18, head, 12, Align::centre);
    std::string sub;
    if (std::isfinite(r.fitThreshold)) {
        sub = "fit JND " + fmt3(r.fitThreshold) + " %";
        if (std::isfinite(r.fitInterval.lo))
            sub += " [" + fmt3(r.fitInterval.lo) + ", " + fmt3(r.fitInterval.hi) + "]";
    }
    if (std::isfinite(r.procedureThreshold))
        sub += (sub.empty() ? "" : "; ") + std::string("reversals ") + fmt3(r.procedureThreshold) +
               " %";
    if (sub.empty()) sub = r.note;
    text(cr, f.x0 + f.w / 2, 34, sub, 10, Align::centre);
}

}  // namespace

void writePsychometricPlot(const std::filesystem::path& stem,
                           const std::vector<ConditionResult>& results, const std::string& title,
                           double coverage) {
    if (results.empty()) throw ValueError("psychometric plot: expected at least one condition");
    const double w = kPanelW * static_cast<double>(results.size());
    const double h = kPanelH + 40;
    cairo_pages::writeAll(stem, w, h, [&](cairo_t* cr) {
        text(cr, w / 2, 22, title, 14, Align::centre);
        cairo_save(cr);
        cairo_translate(cr, 0, 34);
        for (std::size_t i = 0; i < results.size(); ++i)
            panel(cr, results[i], kPanelW * static_cast<double>(i), coverage);
        cairo_restore(cr);
        text(cr, w / 2, h - 6,
             "discs: proportion correct (area ~ trials); line: ML fit; band: " +
                 fmt3(100 * coverage) +
                 " % bootstrap; red: JND at the target with its interval; green: reversals",
             9, Align::centre);
    });
}

}  // namespace palp::haptics
