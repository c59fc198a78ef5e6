#include "palp/studies/map_svg.h"

#include <cmath>
#include <cstdio>
#include <string>

#include "map_util.h"
#include "palp/base/atomic_file.h"

namespace palp::haptics {

namespace {

std::string hex(const std::array<std::uint8_t, 3>& c) {
    char buf[8];
    std::snprintf(buf, sizeof buf, "#%02x%02x%02x", c[0], c[1], c[2]);
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

std::string text(const FigureText& t) {
    static constexpr const char* kAnchor[] = {"start", "middle", "end"};
    std::string s = "<text class=\"" + t.cls + "\" x=\"" + num(t.x) + "\" y=\"" + num(t.y) +
                    "\" text-anchor=\"" + kAnchor[static_cast<int>(t.anchor)] + "\" font-size=\"" +
                    num(t.size) + "\"";
    if (t.bold) s += " font-weight=\"bold\"";
    if (t.vertical) s += " transform=\"rotate(-90 " + num(t.x) + " " + num(t.y) + ")\"";
    return s + ">" + escape(t.body) + "</text>\n";
}

std::string rect(double x, double y, double w, double h, const std::string& rest) {
    return "<rect x=\"" + num(x) + "\" y=\"" + num(y) + "\" width=\"" + num(w) + "\" height=\"" +
           num(h) + "\" " + rest + "/>\n";
}

}  // namespace

void writeMapSvg(const std::filesystem::path& path, const ScalarMap& map, const MapFigure& figure) {
    const MapLayout l = layoutMapFigure(map, figure, 1.0);
    const int cols = map.cols(), rows = map.rows();
    const double s = l.cell;
    std::string svg = "<?xml version=\"1.0\" encoding=\"UTF-8\"?>\n";
    svg += "<svg xmlns=\"http://www.w3.org/2000/svg\" width=\"" + num(l.width) + "\" height=\"" +
           num(l.height) + "\" viewBox=\"0 0 " + num(l.width) + " " + num(l.height) +
           "\" font-family=\"DejaVu Sans, sans-serif\">\n";
    svg += rect(0, 0, l.width, l.height, "fill=\"white\"");

    // The underlay, then the map: one rect per pixel, image row 0 = the largest v.
    const bool under = figure.underlay.has_value();
    if (under) {
        const MapUnderlay& u = *figure.underlay;
        svg += "<g class=\"underlay\" shape-rendering=\"crispEdges\">\n";
        const double us = l.underCell;  // the underlay's pixels may be finer than the map's
        const int urows = u.map.rows();
        for (int row = 0; row < urows; ++row) {
            for (int col = 0; col < u.map.cols(); ++col) {
                const double v = u.map.at(col, row);
                const double x = l.mapX + col * us, y = l.mapY + (urows - 1 - row) * us;
                if (!std::isfinite(v)) {
                    svg += rect(x, y, us, us, "fill=\"#000040\"");
                    continue;
                }
                const double g = unit(v, l.underLo, l.underHi);
                svg += rect(x, y, us, us,
                            "fill=\"" + hex(underlayColour(g, u.brightLow)) + "\" data-u=\"" +
                                num(v) + "\"");
            }
        }
        svg += "</g>\n";
    }
    svg += "<g class=\"map\" shape-rendering=\"crispEdges\"";
    if (under) svg += " opacity=\"" + num(figure.mapOpacity) + "\"";
    svg += ">\n";
    for (int row = 0; row < rows; ++row) {
        for (int col = 0; col < cols; ++col) {
            const double v = map.at(col, row);
            const double x = l.mapX + col * s, y = l.mapY + (rows - 1 - row) * s;
            if (std::isfinite(v)) {
                svg += rect(x, y, s, s,
                            "fill=\"" + hex(mapColour(unit(v, l.lo, l.hi), figure.colorMap)) +
                                "\" data-v=\"" + num(v) + "\"");
            } else if (!under) {
                svg += rect(x, y, s, s, "fill=\"#000040\"");
            }
        }
    }
    svg += "</g>\n" + rect(l.mapX, l.mapY, l.mapW, l.mapH, "fill=\"none\" stroke=\"black\"");

    // The bars: a gradient each, lo at the bottom.
    int id = 0;
    for (const FigureBar* b : {&l.bar, l.underBar ? &*l.underBar : nullptr}) {
        if (!b) continue;
        const std::string name = "bar" + std::to_string(id++);
        svg += "<defs><linearGradient id=\"" + name + "\" x1=\"0\" y1=\"1\" x2=\"0\" y2=\"0\">\n";
        for (int k = 0; k <= 16; ++k) {
            const double f = k / 16.0;
            svg += "<stop offset=\"" + num(f) + "\" stop-color=\"" +
                   hex(mapColour(b->from + (b->to - b->from) * f, b->colorMap)) + "\"/>\n";
        }
        svg += "</linearGradient></defs>\n";
        svg += rect(b->x, b->y, b->w, b->h, "fill=\"url(#" + name + ")\" stroke=\"black\"");
    }
    for (const FigureLine& ln : l.lines) {
        svg += "<line x1=\"" + num(ln.x1) + "\" y1=\"" + num(ln.y1) + "\" x2=\"" + num(ln.x2) +
               "\" y2=\"" + num(ln.y2) + "\" stroke=\"black\"/>\n";
    }
    for (const FigureText& t : l.texts) svg += text(t);
    svg += "</svg>\n";
    palp::writeFileAtomically(path, "map SVG", svg.data(), svg.size());
}

}  // namespace palp::haptics
