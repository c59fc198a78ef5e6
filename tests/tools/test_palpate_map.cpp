// `palp palpate --map FILE.svg`: a map a clinician can read (issue 17). The figure's text names
// its axes in millimetres with the patient directions at their ends, its colour bar in the
// quantity's units and a title; and its pixel-to-millimetre mapping (read back from the tick
// labels, as a reader would) puts the AVC phantom's hidden box where the phantom put it.
#include <gtest/gtest.h>

#include <algorithm>
#include <fstream>
#include <map>
#include <regex>
#include <sstream>
#include <string>
#include <vector>

#include "palp/volume/phantom.h"
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

}  // namespace
