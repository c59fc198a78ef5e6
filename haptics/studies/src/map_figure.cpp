#include "palp/studies/map_figure.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <string>

#include "map_util.h"
#include "palp/base/error.h"

namespace palp::haptics {

namespace {

// Layout at scale 1, px.
constexpr double kLeft = 90, kRight = 130, kTop = 56, kBottom = 70;
constexpr double kBarWidth = 18, kBarGap = 22;
constexpr double kBarLabel = 62;    // from a bar's right edge to its (vertical) label
constexpr double kUnderBar = 100;   // from the colour bar to the underlay's bar
constexpr double kMapSide = 480;    // the map's longer side
constexpr double kCharWidth = 0.6;  // a generous width of a character, in font sizes

/// A step of 1, 2 or 5 x 10^k giving 4-8 ticks over @p span.
double niceStep(double span) {
    if (!(span > 0) || !std::isfinite(span)) return 1;
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

/// The value range of a map: @p lo, @p hi where finite, else the map's own.
void valueRange(const ScalarMap& map, double lo, double hi, double& outLo, double& outHi) {
    double mn = 0, mx = 0;
    map.range(mn, mx);
    outLo = std::isfinite(lo) ? lo : mn;
    outHi = std::isfinite(hi) ? hi : mx;
}

/// Ticks and labels of a vertical bar from @p lo (bottom) to @p hi (top), its label at the right.
void barTicks(MapLayout& l, const FigureBar& bar, double lo, double hi, const std::string& cls,
              const std::string& label, double k) {
    if (std::isfinite(lo) && std::isfinite(hi)) {
        const double step = niceStep(hi - lo);
        for (double t = std::ceil(lo / step - 1e-9) * step; t <= hi + 1e-9 * step; t += step) {
            const double y = bar.y + bar.h - (hi > lo ? (t - lo) / (hi - lo) : 0.0) * bar.h;
            l.lines.push_back({bar.x + bar.w, y, bar.x + bar.w + 5 * k, y});
            l.texts.push_back({cls + "-tick", num(std::abs(t) < 1e-9 * step ? 0.0 : t),
                               bar.x + bar.w + 8 * k, y + 4 * k, 11 * k,
                               FigureText::Anchor::Start});
        }
    }
    l.texts.push_back({cls, label, bar.x + bar.w + kBarLabel * k, bar.y + bar.h / 2, 13 * k,
                       FigureText::Anchor::Middle, false, true});
}

}  // namespace

const char* patientDirection(const Eigen::Vector3d& axis) noexcept {
    int i = 0;
    axis.cwiseAbs().maxCoeff(&i);
    static constexpr const char* kPos[] = {"L", "P", "S"};
    static constexpr const char* kNeg[] = {"R", "A", "I"};
    return axis[i] >= 0 ? kPos[i] : kNeg[i];
}

std::array<std::uint8_t, 3> mapColour(double s, ColorMap colorMap) noexcept {
    s = std::isfinite(s) ? std::clamp(s, 0.0, 1.0) : 0.0;
    const auto c = [](double x) {
        return static_cast<std::uint8_t>(std::lround(255.0 * std::clamp(x, 0.0, 1.0)));
    };
    if (colorMap == ColorMap::Heat) return {c(3 * s), c(3 * s - 1), c(3 * s - 2)};
    return {c(s), c(s), c(s)};
}

std::array<std::uint8_t, 3> underlayColour(double s, bool brightLow) noexcept {
    s = std::isfinite(s) ? std::clamp(s, 0.0, 1.0) : 0.0;
    if (brightLow) s = 1 - s;
    return mapColour(kUnderlayGreyLo + (kUnderlayGreyHi - kUnderlayGreyLo) * s, ColorMap::Grey);
}

MapLayout layoutMapFigure(const ScalarMap& map, const MapFigure& figure, double k) {
    if (!(k >= 0.25 && k <= 8)) {
        throw ValueError("map figure: expected a scale of 0.25-8, found " + num(k));
    }
    if (!(figure.mapOpacity > 0 && figure.mapOpacity <= 1)) {
        throw ValueError("map figure: expected a map opacity in (0, 1], found " +
                         num(figure.mapOpacity));
    }
    const MapPlane& plane = map.plane();
    const double cover = plane.pixelM * 1e-6;  // how closely the underlay must cover the map
    if (figure.underlay) {
        const ScalarMap& um = figure.underlay->map;
        const MapPlane& up = um.plane();
        if (up.u != plane.u || up.v != plane.v || !(up.pixelM <= plane.pixelM * (1 + 1e-9)) ||
            std::abs(um.cols() * up.pixelM - map.cols() * plane.pixelM) > cover ||
            std::abs(um.rows() * up.pixelM - map.rows() * plane.pixelM) > cover ||
            std::abs((up.centre - plane.centre).dot(plane.u)) > cover ||
            std::abs((up.centre - plane.centre).dot(plane.v)) > cover) {
            throw ValueError(
                "map figure: expected an underlay covering the map's pixels on its plane (same "
                "axes, centre and area, pixels as fine or finer), found another plane");
        }
    }
    MapLayout l;
    const int cols = map.cols(), rows = map.rows();
    // Square map pixels, the longer side about 480 px (at scale 1).
    l.cell = k * std::clamp(kMapSide / std::max(cols, rows), 1.0, 32.0);
    l.mapW = cols * l.cell;
    l.mapH = rows * l.cell;
    l.mapX = kLeft * k;
    l.mapY = kTop * k;
    if (figure.underlay) l.underCell = l.cell * figure.underlay->map.plane().pixelM / plane.pixelM;
    const double right = (kRight + (figure.underlay ? kUnderBar : 0.0)) * k;
    l.width = l.mapX + l.mapW + right;
    // Room for the title (a generous estimate of its width).
    l.width =
        std::max(l.width, (kCharWidth * 14 * static_cast<double>(figure.title.size()) + 40) * k);
    l.height = l.mapY + l.mapH + kBottom * k;
    valueRange(map, figure.lo, figure.hi, l.lo, l.hi);
    l.texts.push_back(
        {"title", figure.title, l.width / 2, 24 * k, 14 * k, FigureText::Anchor::Middle, true});

    // Axes: world coordinates (mm) along u (bottom) and v (left). Pixel edges lie at
    // a = -extent/2 + col pixelM from the plane's centre (MapPlane::pixelCentre).
    const double pu = plane.pixelM * 1e3;
    for (const bool horizontal : {true, false}) {
        const Eigen::Vector3d& axis = horizontal ? plane.u : plane.v;
        const int n = horizontal ? cols : rows;
        const Eigen::Vector3d e = axis.cwiseAbs();  // the world axis, positive
        const double sign = axis.dot(e) >= 0 ? 1 : -1;
        const double c0 = plane.pixelCentre(0, 0).dot(e) * 1e3 - sign * 0.5 * pu;  // near edge
        const double c1 = c0 + sign * n * pu;  // world coordinate at the far edge
        if (horizontal) {
            l.u0 = c0;
            l.uPerPx = (c1 - c0) / l.mapW;
        } else {
            l.v0 = c0;
            l.vPerPx = (c1 - c0) / l.mapH;
        }
        const double step = niceStep(std::abs(c1 - c0));
        const double first = std::ceil(std::min(c0, c1) / step - 1e-9) * step;
        for (double t = first; t <= std::max(c0, c1) + 1e-9 * step; t += step) {
            const std::string label = num(std::abs(t) < 1e-9 * step ? 0.0 : t);
            if (horizontal) {
                const double x = l.xAtMm(t);
                l.lines.push_back({x, l.mapY + l.mapH, x, l.mapY + l.mapH + 6 * k});
                l.texts.push_back({"tick-u", label, x, l.mapY + l.mapH + 20 * k, 12 * k,
                                   FigureText::Anchor::Middle});
            } else {
                const double y = l.yAtMm(t);
                l.lines.push_back({l.mapX - 6 * k, y, l.mapX, y});
                l.texts.push_back(
                    {"tick-v", label, l.mapX - 9 * k, y + 4 * k, 12 * k, FigureText::Anchor::End});
            }
        }
        const std::string name = std::string(1, axisLetter(axis)) + " (mm)";
        const char* nearDir = patientDirection(-axis);
        const char* farDir = patientDirection(axis);
        if (horizontal) {
            const double y = l.mapY + l.mapH + 44 * k;
            l.texts.push_back(
                {"axis-u", name, l.mapX + l.mapW / 2, y, 13 * k, FigureText::Anchor::Middle});
            l.texts.push_back(
                {"direction", nearDir, l.mapX, y, 15 * k, FigureText::Anchor::Start, true});
            l.texts.push_back(
                {"direction", farDir, l.mapX + l.mapW, y, 15 * k, FigureText::Anchor::End, true});
        } else {
            const double x = 22 * k;
            l.texts.push_back({"axis-v", name, x, l.mapY + l.mapH / 2, 13 * k,
                               FigureText::Anchor::Middle, false, true});
            l.texts.push_back({"direction", nearDir, x + 12 * k, l.mapY + l.mapH, 15 * k,
                               FigureText::Anchor::Middle, true});
            l.texts.push_back({"direction", farDir, x + 12 * k, l.mapY + 12 * k, 15 * k,
                               FigureText::Anchor::Middle, true});
        }
    }

    // Colour bar: lo at the bottom, hi at the top; the underlay's grey bar to its right.
    l.bar = {l.mapX + l.mapW + kBarGap * k, l.mapY, kBarWidth * k, l.mapH, figure.colorMap, 0, 1};
    barTicks(l, l.bar, l.lo, l.hi, "colorbar", figure.quantity + " (" + figure.units + ")", k);
    if (figure.underlay) {
        const MapUnderlay& u = *figure.underlay;
        valueRange(u.map, u.lo, u.hi, l.underLo, l.underHi);
        const double dark = kUnderlayGreyLo, light = kUnderlayGreyHi;
        FigureBar ub{l.bar.x + kUnderBar * k,
                     l.mapY,
                     kBarWidth * k,
                     l.mapH,
                     ColorMap::Grey,
                     u.brightLow ? light : dark,
                     u.brightLow ? dark : light};
        l.underBar = ub;
        // A range under a millimetre reads in micrometres: the demo's skin lies 22-33 um under
        // the plane (the iso-surface between the air and fat voxels), which as "0.024 mm" reads
        // like metres mislabelled.
        const double reach = std::max(std::abs(l.underLo), std::abs(l.underHi));
        const bool micro = u.units == "mm" && reach < 1;
        const double scale = micro ? 1e3 : 1.0;
        barTicks(l, ub, l.underLo * scale, l.underHi * scale, "underlay",
                 u.quantity + " (" + (micro ? std::string("\u00b5m") : u.units) + ")", k);
    }
    return l;
}

}  // namespace palp::haptics
