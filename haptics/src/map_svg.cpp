#include "palp/haptics/map_svg.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <string>

#include "palp/base/atomic_file.h"

namespace palp::haptics {

namespace {

// Layout, SVG user units (px).
constexpr double kLeft = 90, kRight = 130, kTop = 56, kBottom = 70;
constexpr double kBarWidth = 18, kBarGap = 22;

std::string colour(double s, ColorMap cm) {
    s = std::clamp(s, 0.0, 1.0);
    const auto c = [](double x) {
        return static_cast<int>(std::lround(255 * std::clamp(x, 0.0, 1.0)));
    };
    int r = 0, g = 0, b = 0;
    if (cm == ColorMap::Heat) {
        r = c(3 * s);  // black -> red -> yellow -> white, as writeMapPng()
        g = c(3 * s - 1);
        b = c(3 * s - 2);
    } else {
        r = g = b = c(s);
    }
    char buf[8];
    std::snprintf(buf, sizeof buf, "#%02x%02x%02x", r, g, b);
    return buf;
}

std::string escape(const std::string& text) {
    std::string out;
    for (char ch : text) {
        switch (ch) {
            case '&':
                out += "&amp;";
                break;
            case '<':
                out += "&lt;";
                break;
            case '>':
                out += "&gt;";
                break;
            case '"':
                out += "&quot;";
                break;
            default:
                out += ch;
        }
    }
    return out;
}

std::string num(double x) {
    char buf[32];
    std::snprintf(buf, sizeof buf, "%.6g", x);
    return buf;
}

std::string text(double x, double y, const std::string& cls, const std::string& anchor,
                 const std::string& body, double size = 12, const std::string& extra = "") {
    return "<text class=\"" + cls + "\" x=\"" + num(x) + "\" y=\"" + num(y) + "\" text-anchor=\"" +
           anchor + "\" font-size=\"" + num(size) + "\"" + extra + ">" + escape(body) + "</text>\n";
}

/// A step of 1, 2 or 5 x 10^k giving 4-8 ticks over @p span.
double niceStep(double span) {
    if (!(span > 0)) return 1;
    const double raw = span / 6;
    const double p = std::pow(10.0, std::floor(std::log10(raw)));
    for (double m : {1.0, 2.0, 5.0, 10.0})
        if (m * p >= raw) return m * p;
    return 10 * p;
}

/// Axis name of the world axis @p a points along: "x", "y" or "z".
char axisLetter(const Eigen::Vector3d& a) {
    int i = 0;
    a.cwiseAbs().maxCoeff(&i);
    return "xyz"[i];
}

}  // namespace

const char* patientDirection(const Eigen::Vector3d& axis) noexcept {
    int i = 0;
    axis.cwiseAbs().maxCoeff(&i);
    static constexpr const char* kPos[] = {"L", "P", "S"};
    static constexpr const char* kNeg[] = {"R", "A", "I"};
    return axis[i] >= 0 ? kPos[i] : kNeg[i];
}

void writeMapSvg(const std::filesystem::path& path, const ScalarMap& map, const MapFigure& figure) {
    const MapPlane& plane = map.plane();
    const int cols = map.cols(), rows = map.rows();
    // Square map pixels, the longer side about 480 px.
    const double s = std::clamp(480.0 / std::max(cols, rows), 1.0, 32.0);
    const double w = cols * s, h = rows * s;
    const double width = kLeft + w + kRight, height = kTop + h + kBottom;
    double lo = figure.lo, hi = figure.hi, mn = 0, mx = 0;
    map.range(mn, mx);
    if (!std::isfinite(lo)) lo = mn;
    if (!std::isfinite(hi)) hi = mx;
    const double span = std::isfinite(lo) && std::isfinite(hi) && hi > lo ? hi - lo : 1.0;

    std::string svg = "<?xml version=\"1.0\" encoding=\"UTF-8\"?>\n";
    svg += "<svg xmlns=\"http://www.w3.org/2000/svg\" width=\"" + num(width) + "\" height=\"" +
           num(height) + "\" viewBox=\"0 0 " + num(width) + " " + num(height) +
           "\" font-family=\"sans-serif\">\n";
    svg += "<rect x=\"0\" y=\"0\" width=\"" + num(width) + "\" height=\"" + num(height) +
           "\" fill=\"white\"/>\n";
    svg += text(width / 2, 24, "title", "middle", figure.title, 14);

    // The map: one rect per pixel, image row 0 = the largest v.
    svg += "<g class=\"map\" shape-rendering=\"crispEdges\">\n";
    for (int row = 0; row < rows; ++row) {
        for (int col = 0; col < cols; ++col) {
            const double v = map.at(col, row);
            const double x = kLeft + col * s, y = kTop + (rows - 1 - row) * s;
            svg += "<rect x=\"" + num(x) + "\" y=\"" + num(y) + "\" width=\"" + num(s) +
                   "\" height=\"" + num(s) + "\" fill=\"";
            if (std::isfinite(v)) {
                svg += colour(std::isfinite(lo) ? (v - lo) / span : 0, figure.colorMap) +
                       "\" data-v=\"" + num(v) + "\"/>\n";
            } else {
                svg += "#000040\"/>\n";
            }
        }
    }
    svg += "</g>\n<rect x=\"" + num(kLeft) + "\" y=\"" + num(kTop) + "\" width=\"" + num(w) +
           "\" height=\"" + num(h) + "\" fill=\"none\" stroke=\"black\"/>\n";

    // Axes: world coordinates (mm) along u (bottom) and v (left). Pixel edges lie at
    // a = -extentU/2 + col pixelM from the plane's centre (MapPlane::pixelCentre).
    const double pu = plane.pixelM * 1e3;
    const struct {
        const Eigen::Vector3d* axis;
        int n;
        bool horizontal;
    } axes[] = {{&plane.u, cols, true}, {&plane.v, rows, false}};
    for (const auto& ax : axes) {
        const Eigen::Vector3d e = ax.axis->cwiseAbs();  // the world axis, positive
        const double sign = ax.axis->dot(e) >= 0 ? 1 : -1;
        const double c0 = plane.pixelCentre(0, 0).dot(e) * 1e3 - sign * 0.5 * pu;  // edge
        const double c1 = c0 + sign * ax.n * pu;  // world coordinate at the far edge
        const double step = niceStep(std::abs(c1 - c0));
        const double first = std::ceil(std::min(c0, c1) / step - 1e-9) * step;
        const std::string cls = ax.horizontal ? "tick-u" : "tick-v";
        for (double t = first; t <= std::max(c0, c1) + 1e-9 * step; t += step) {
            const double f = (t - c0) / (c1 - c0);  // 0 at the near edge, 1 at the far edge
            const double label = std::abs(t) < 1e-9 * step ? 0.0 : t;
            if (ax.horizontal) {
                const double x = kLeft + f * w;
                svg += "<line x1=\"" + num(x) + "\" y1=\"" + num(kTop + h) + "\" x2=\"" + num(x) +
                       "\" y2=\"" + num(kTop + h + 6) + "\" stroke=\"black\"/>\n";
                svg += text(x, kTop + h + 20, cls, "middle", num(label));
            } else {
                const double y = kTop + h - f * h;
                svg += "<line x1=\"" + num(kLeft - 6) + "\" y1=\"" + num(y) + "\" x2=\"" +
                       num(kLeft) + "\" y2=\"" + num(y) + "\" stroke=\"black\"/>\n";
                svg += text(kLeft - 9, y + 4, cls, "end", num(label));
            }
        }
        const std::string name = std::string(1, axisLetter(*ax.axis)) + " (mm)";
        const Eigen::Vector3d neg = -*ax.axis;
        if (ax.horizontal) {
            svg += text(kLeft + w / 2, kTop + h + 44, "axis-u", "middle", name, 13);
            svg += text(kLeft, kTop + h + 44, "direction", "start", patientDirection(neg), 15,
                        " font-weight=\"bold\"");
            svg += text(kLeft + w, kTop + h + 44, "direction", "end", patientDirection(*ax.axis),
                        15, " font-weight=\"bold\"");
        } else {
            const double x = 22, y = kTop + h / 2;
            svg += text(x, y, "axis-v", "middle", name, 13,
                        " transform=\"rotate(-90 " + num(x) + " " + num(y) + ")\"");
            svg += text(x + 12, kTop + h, "direction", "middle", patientDirection(neg), 15,
                        " font-weight=\"bold\"");
            svg += text(x + 12, kTop + 12, "direction", "middle", patientDirection(*ax.axis), 15,
                        " font-weight=\"bold\"");
        }
    }

    // Colour bar: lo at the bottom, hi at the top.
    const double bx = kLeft + w + kBarGap;
    svg += "<defs><linearGradient id=\"bar\" x1=\"0\" y1=\"1\" x2=\"0\" y2=\"0\">\n";
    for (int k = 0; k <= 16; ++k) {
        svg += "<stop offset=\"" + num(k / 16.0) + "\" stop-color=\"" +
               colour(k / 16.0, figure.colorMap) + "\"/>\n";
    }
    svg += "</linearGradient></defs>\n";
    svg += "<rect x=\"" + num(bx) + "\" y=\"" + num(kTop) + "\" width=\"" + num(kBarWidth) +
           "\" height=\"" + num(h) + "\" fill=\"url(#bar)\" stroke=\"black\"/>\n";
    if (std::isfinite(lo) && std::isfinite(hi)) {
        const double step = niceStep(hi - lo);
        for (double t = std::ceil(lo / step - 1e-9) * step; t <= hi + 1e-9 * step; t += step) {
            const double y = kTop + h - (hi > lo ? (t - lo) / (hi - lo) : 0.0) * h;
            svg += "<line x1=\"" + num(bx + kBarWidth) + "\" y1=\"" + num(y) + "\" x2=\"" +
                   num(bx + kBarWidth + 5) + "\" y2=\"" + num(y) + "\" stroke=\"black\"/>\n";
            svg += text(bx + kBarWidth + 8, y + 4, "colorbar-tick", "start",
                        num(std::abs(t) < 1e-9 * step ? 0.0 : t), 11);
        }
    }
    const double lx = bx + kBarWidth + 62, ly = kTop + h / 2;
    svg += text(lx, ly, "colorbar", "middle", figure.quantity + " (" + figure.units + ")", 13,
                " transform=\"rotate(-90 " + num(lx) + " " + num(ly) + ")\"");
    svg += "</svg>\n";
    palp::writeFileAtomically(path, "map SVG", svg.data(), svg.size());
}

}  // namespace palp::haptics
