// `palp palpate --map FILE.svg|png`: a map a clinician can read (issue 17). The figure's text
// names its axes in millimetres with the patient directions at their ends, its colour bar in the
// quantity's units and a title; and its pixel-to-millimetre mapping (read back from the tick
// labels, as a reader would) puts the AVC phantom's hidden box where the phantom put it. The PNG
// (drawn with cairo from the same layout) does the same through the mapping --json reports, its
// tick marks lie on round millimetres, its bar, axes and title are drawn; bad values leave no
// file behind.
#include <gtest/gtest.h>
#include <png.h>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <map>
#include <nlohmann/json.hpp>
#include <regex>
#include <sstream>
#include <string>
#include <vector>

#include "palp/volume/phantom.h"
#include "png_image.h"
#include "test_support.h"

namespace {

using palp::test::runCommand;

struct SvgText {
    std::string cls;
    double x = 0, y = 0;
    std::string body;
};

struct SvgCell {
    double x = 0, y = 0, size = 0, value = 0;
};

/// Least-squares line through (px, mm) pairs: mm = a + b px; @p worst: the largest residual.
void fitLine(const std::vector<std::pair<double, double>>& p, double& a, double& b, double& worst) {
    double sx = 0, sy = 0, sxx = 0, sxy = 0;
    for (const auto& [x, y] : p) {
        sx += x;
        sy += y;
        sxx += x * x;
        sxy += x * y;
    }
    const double n = static_cast<double>(p.size());
    b = (n * sxy - sx * sy) / (n * sxx - sx * sx);
    a = (sy - b * sx) / n;
    worst = 0;
    for (const auto& [x, y] : p) worst = std::max(worst, std::abs(a + b * x - y));
}

TEST(PalpateMap, SvgHasAxesInMmDirectionsColourBarTitleAndTheHiddenBoxInPlace) {
    for (int quadrant : {1, 2}) {
        palp::test::TempDir tmp;
        const std::string svg = (tmp / "m.svg").string();
        const auto r = runCommand(palp::test::palpTool().string() +
                                  " palpate --phantom avc --map-at ray-end --quadrant " +
                                  std::to_string(quadrant) + " --map " + svg);
        ASSERT_EQ(r.exitCode, 0) << r.output;
        std::ifstream in(svg);
        std::stringstream ss;
        ss << in.rdbuf();
        const std::string text = ss.str();
        ASSERT_NE(text.find("<svg"), std::string::npos);

        std::vector<SvgText> texts;
        const std::regex te(
            R"re(<text class="([^"]+)" x="([^"]+)" y="([^"]+)"[^>]*>([^<]*)</text>)re");
        for (auto it = std::sregex_iterator(text.begin(), text.end(), te);
             it != std::sregex_iterator(); ++it) {
            texts.push_back({(*it)[1], std::stod((*it)[2]), std::stod((*it)[3]), (*it)[4]});
        }
        std::multimap<std::string, std::string> byClass;
        for (const SvgText& t : texts) byClass.emplace(t.cls, t.body);
        const auto has = [&](const std::string& cls, const std::string& body) {
            const auto [b, e] = byClass.equal_range(cls);
            return std::any_of(b, e, [&](const auto& kv) { return kv.second == body; });
        };
        // The phantom's surface faces the examiner: u = +x (R to L), v = +z (I to S).
        EXPECT_TRUE(has("axis-u", "x (mm)"));
        EXPECT_TRUE(has("axis-v", "z (mm)"));
        for (const char* d : {"R", "L", "I", "S"}) EXPECT_TRUE(has("direction", d)) << d;
        EXPECT_TRUE(has("colorbar", "stiffness (N/m)"));
        EXPECT_GE(byClass.count("colorbar-tick"), 3u);
        ASSERT_EQ(byClass.count("title"), 1u);
        const std::string title = byClass.find("title")->second;
        for (const char* part : {"avc quadrant=", "avc/accumulate", "raster", "from A"})
            EXPECT_NE(title.find(part), std::string::npos) << title;

        // Pixel to millimetre, from the tick labels (x for u, y for v).
        std::vector<std::pair<double, double>> tu, tv;
        for (const SvgText& t : texts) {
            if (t.cls == "tick-u") tu.push_back({t.x, std::stod(t.body)});
            if (t.cls == "tick-v") tv.push_back({t.y, std::stod(t.body)});
        }
        ASSERT_GE(tu.size(), 3u);
        ASSERT_GE(tv.size(), 3u);
        double au = 0, bu = 0, eu = 0, av = 0, bv = 0, ev = 0;
        fitLine(tu, au, bu, eu);
        fitLine(tv, av, bv, ev);
        EXPECT_LT(eu, 1e-3);  // the ticks are evenly spaced: one linear map
        EXPECT_LT(ev, 1e-3);
        EXPECT_GT(bu, 0);  // +x to the right
        EXPECT_LT(bv, 0);  // +z up (SVG y grows downward)

        // The cells felt stiffest (top quarter of the range): their centroid in mm.
        std::vector<SvgCell> cells;
        const std::regex re(
            R"re(<rect x="([^"]+)" y="([^"]+)" width="([^"]+)" height="[^"]+" fill="[^"]+" data-v="([^"]+)"/>)re");
        for (auto it = std::sregex_iterator(text.begin(), text.end(), re);
             it != std::sregex_iterator(); ++it) {
            cells.push_back({std::stod((*it)[1]), std::stod((*it)[2]), std::stod((*it)[3]),
                             std::stod((*it)[4])});
        }
        ASSERT_GT(cells.size(), 100u);
        const auto [mn, mx] = std::minmax_element(
            cells.begin(), cells.end(),
            [](const SvgCell& a, const SvgCell& b) { return a.value < b.value; });
        const double cut = mn->value + 0.75 * (mx->value - mn->value);
        double cx = 0, cz = 0, n = 0;
        for (const SvgCell& c : cells) {
            if (c.value < cut) continue;
            cx += au + bu * (c.x + 0.5 * c.size);
            cz += av + bv * (c.y + 0.5 * c.size);
            ++n;
        }
        ASSERT_GT(n, 0);
        cx /= n;
        cz /= n;
        const auto box = palp::volume::Phantom::avcHiddenBox(quadrant);
        std::printf(
            "quadrant %d: stiffest cells centred at (%.1f, %.1f) mm; box x %.1f..%.1f, "
            "z %.1f..%.1f mm\n",
            quadrant, cx, cz, box.min.x() * 1e3, box.max.x() * 1e3, box.min.z() * 1e3,
            box.max.z() * 1e3);
        EXPECT_GT(cx, box.min.x() * 1e3);
        EXPECT_LT(cx, box.max.x() * 1e3);
        EXPECT_GT(cz, box.min.z() * 1e3);
        EXPECT_LT(cz, box.max.z() * 1e3);
    }
}

using palp::test::readPng;
using palp::test::Rgb;

TEST(PalpateMap, PngFigurePutsTheHiddenBoxInPlaceWithTicksOnRoundMillimetres) {
    palp::test::TempDir tmp;
    const std::string png = (tmp / "m.png").string();
    const int quadrant = 1;
    const auto r = runCommand(palp::test::palpTool().string() +
                              " palpate --phantom avc --map-at ray-end --quadrant " +
                              std::to_string(quadrant) + " --map " + png + " --json");
    ASSERT_EQ(r.exitCode, 0) << r.output;
    const auto j = nlohmann::json::parse(r.output.substr(r.output.find('{')));
    EXPECT_EQ(j["map_underlay"], "none");  // a phantom's default: its skin is flat
    const auto& fig = j["map_image"];
    const std::vector<double> m = fig["map_px"], um = fig["u_mm"], vm = fig["v_mm"];
    const Rgb img = readPng(png);
    ASSERT_FALSE(img.px.empty());
    ASSERT_EQ(img.w, fig["width_px"].get<int>());
    ASSERT_EQ(img.h, fig["height_px"].get<int>());
    const double x0 = m[0], y0 = m[1], x1 = m[0] + m[2], y1 = m[1] + m[3];
    const auto mmX = [&](double x) { return um[0] + (um[1] - um[0]) * (x - x0) / (x1 - x0); };
    const auto mmY = [&](double y) { return vm[0] + (vm[1] - vm[0]) * (y1 - y) / (y1 - y0); };

    // The pixels felt stiffest (heat: r + g + b grows linearly with the value; top quarter):
    // their centroid in mm lies over the hidden box.
    double cx = 0, cz = 0, n = 0;
    for (int y = static_cast<int>(y0) + 2; y < static_cast<int>(y1) - 2; ++y) {
        for (int x = static_cast<int>(x0) + 2; x < static_cast<int>(x1) - 2; ++x) {
            const unsigned char* p = img.at(x, y);
            if (p[0] + p[1] + p[2] < 0.75 * 765) continue;
            cx += mmX(x + 0.5);
            cz += mmY(y + 0.5);
            ++n;
        }
    }
    ASSERT_GT(n, 50);
    cx /= n;
    cz /= n;
    const auto box = palp::volume::Phantom::avcHiddenBox(quadrant);
    std::printf("PNG: stiffest pixels centred at (%.1f, %.1f) mm; box x %.1f..%.1f, z %.1f..%.1f\n",
                cx, cz, box.min.x() * 1e3, box.max.x() * 1e3, box.min.z() * 1e3, box.max.z() * 1e3);
    EXPECT_GT(cx, box.min.x() * 1e3);
    EXPECT_LT(cx, box.max.x() * 1e3);
    EXPECT_GT(cz, box.min.z() * 1e3);
    EXPECT_LT(cz, box.max.z() * 1e3);

    // The tick marks under the map (dark runs of columns just below its frame) lie on round
    // millimetres (multiples of 5) by that mapping.
    std::vector<double> ticks;
    for (int x = static_cast<int>(x0) - 3, run = 0; x < static_cast<int>(x1) + 4; ++x) {
        const bool dark = img.lum(x, static_cast<int>(y1) + 4) < 100;
        if (dark) ++run;
        if (!dark && run > 0) {
            ticks.push_back(mmX(x - run / 2.0));
            run = 0;
        }
    }
    ASSERT_GE(ticks.size(), 3u);
    for (double t : ticks) EXPECT_NEAR(t, 5 * std::round(t / 5), 0.5) << t;

    // Drawn: the colour bar (a column right of the map, black at the bottom, white at the top),
    // the axes' labels under and left of the map, the title above it.
    bool bar = false;
    for (int x = static_cast<int>(x1) + 5; x < static_cast<int>(x1) + 80 && !bar; ++x)
        bar =
            img.lum(x, static_cast<int>(y1) - 3) < 30 && img.lum(x, static_cast<int>(y0) + 3) > 225;
    EXPECT_TRUE(bar);
    const auto dark = [&](double xa, double ya, double xb, double yb) {
        int count = 0;
        for (int y = static_cast<int>(ya); y < static_cast<int>(yb); ++y)
            for (int x = static_cast<int>(xa); x < static_cast<int>(xb); ++x)
                count += img.lum(x, y) < 100;
        return count;
    };
    EXPECT_GT(dark(x0, y1 + 12, x1, img.h), 300);  // tick labels, "x (mm)", R, L
    EXPECT_GT(dark(0, y0, x0 - 12, y1), 300);      // tick labels, "z (mm)", S, I
    EXPECT_GT(dark(0, 0, img.w, y0 - 4), 300);     // the title
}

TEST(PalpateMap, BadUnderlayOrUnwritableMapLeavesNoFile) {
    palp::test::TempDir tmp;
    const std::string palp = palp::test::palpTool().string() +
                             " palpate --phantom avc --voxel-mm 2 --spacing 4 --trace " +
                             (tmp / "t.csv").string();
    const auto listing = [&] {
        std::vector<std::string> names;
        for (const auto& e : std::filesystem::directory_iterator(tmp.path()))
            names.push_back(e.path().filename().string());
        std::sort(names.begin(), names.end());
        return names;
    };
    auto r = runCommand(palp + " --map " + (tmp / "m.png").string() + " --map-underlay nonsense");
    EXPECT_NE(r.exitCode, 0);
    EXPECT_NE(r.output.find("--map-underlay"), std::string::npos) << r.output;
    EXPECT_NE(r.output.find("nonsense"), std::string::npos) << r.output;
    EXPECT_TRUE(listing().empty());
    r = runCommand(palp + " --map-underlay mip");  // no --map to draw it under
    EXPECT_NE(r.exitCode, 0);
    EXPECT_NE(r.output.find("--map-underlay mip: expected --map"), std::string::npos) << r.output;
    EXPECT_TRUE(listing().empty());
    // A map path that is a directory: refused when the figure is written, naming it; the
    // trace written before it is removed again and no temporary file is left.
    std::filesystem::create_directory(tmp / "d.png");
    r = runCommand(palp + " --map " + (tmp / "d.png").string() + " --map-underlay skin-depth");
    EXPECT_NE(r.exitCode, 0);
    EXPECT_NE(r.output.find((tmp / "d.png").string()), std::string::npos) << r.output;
    EXPECT_EQ(listing(), std::vector<std::string>{"d.png"});
    // The same with a usable path: the phantom's flat skin gives a flat skin-depth underlay.
    r = runCommand(palp + " --map " + (tmp / "u.png").string() +
                   " --map-underlay skin-depth --json");
    ASSERT_EQ(r.exitCode, 0) << r.output;
    const auto j = nlohmann::json::parse(r.output.substr(r.output.find('{')));
    EXPECT_EQ(j["map_underlay"], "skin depth");
    const double lo = j["map_underlay_range"][0], hi = j["map_underlay_range"][1];
    EXPECT_GE(lo, -0.1);
    EXPECT_LT(hi - lo, 0.5);  // flat to within a quarter voxel
}

}  // namespace
