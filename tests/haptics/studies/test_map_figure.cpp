// Map figures (issue 17): the shared layout's pixel-to-millimetre mapping, the PNG drawn with
// cairo from it (read back with libpng: the map where the layout says, the colour bar, axes and
// title drawn), the skin-depth and MIP underlays of a scan with a known tilted skin, and the
// errors (bad scale, foreign underlay, unwritable path: nothing left behind).
#include <gtest/gtest.h>
#include <png.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <string>
#include <vector>

#include "palp/base/error.h"
#include "palp/haptics/scene.h"
#include "palp/studies/map_figure.h"
#include "palp/studies/map_svg.h"
#include "palp/studies/map_underlay.h"
#include "png_image.h"

namespace palp::haptics {
namespace {

namespace fs = std::filesystem;

fs::path tempDir(const std::string& name) {
    fs::path d = fs::temp_directory_path() / ("palp_test_map_figure_" + name);
    fs::remove_all(d);
    fs::create_directories(d);
    return d;
}

using palp::test::readPng;
using palp::test::Rgb;

/// 50 x 30 mm at 2 mm pixels, u = +x, v = +z, on the plane y = 0.
MapPlane testPlane() {
    MapPlane p;
    p.centre = Eigen::Vector3d(0.004, 0, -0.002);
    p.extentU = 0.05;
    p.extentV = 0.03;
    p.pixelM = 0.002;
    return p;
}

TEST(MapFigure, LayoutMapsPixelsToTheWorldMillimetresOfThePlane) {
    const MapPlane plane = testPlane();
    ScalarMap map(plane);
    map.set(0, 0, 1.0);
    map.set(3, 2, 2.0);
    for (const double scale : {1.0, 1.5}) {
        const MapLayout l = layoutMapFigure(map, MapFigure{}, scale);
        EXPECT_NEAR(l.mapW / l.cell, map.cols(), 1e-9);
        EXPECT_NEAR(l.mapH / l.cell, map.rows(), 1e-9);
        // The centre of every map pixel, through the layout, lands on its world position.
        for (int col : {0, 7, 24}) {
            for (int row : {0, 9, 14}) {
                const Eigen::Vector3d w = plane.pixelCentre(col, row) * 1e3;
                const double x = l.mapX + (col + 0.5) * l.cell;
                const double y = l.mapY + (map.rows() - 1 - row + 0.5) * l.cell;
                EXPECT_NEAR(l.mmAtX(x), w.x(), 1e-9);
                EXPECT_NEAR(l.mmAtY(y), w.z(), 1e-9);
                EXPECT_NEAR(l.xAtMm(w.x()), x, 1e-9);
                EXPECT_NEAR(l.yAtMm(w.z()), y, 1e-9);
            }
        }
        // Every u tick's label is the world x under it.
        int ticks = 0;
        for (const FigureText& t : l.texts) {
            if (t.cls != "tick-u") continue;
            EXPECT_NEAR(l.mmAtX(t.x), std::stod(t.body), 1e-6);
            ++ticks;
        }
        EXPECT_GE(ticks, 4);
    }
    // An underlay in pixels a quarter of the map's, over the same rectangle: a quarter of the
    // cell each; one in coarser pixels is refused.
    MapPlane fine = plane;
    fine.extentU = map.cols() * plane.pixelM;
    fine.extentV = map.rows() * plane.pixelM;
    fine.pixelM = plane.pixelM / 4;
    MapFigure withUnder;
    withUnder.underlay.emplace(fine);
    const MapLayout lu = layoutMapFigure(map, withUnder);
    EXPECT_NEAR(lu.underCell, lu.cell / 4, 1e-12);
    EXPECT_NEAR(withUnder.underlay->map.cols() * lu.underCell, lu.mapW, 1e-9);
    {
        // In the SVG: 16 underlay rects per map pixel, tiling the map's rectangle exactly.
        const fs::path dir = tempDir("svg");
        writeMapSvg(dir / "u.svg", map, withUnder);
        std::ifstream in(dir / "u.svg");
        const std::string svg((std::istreambuf_iterator<char>(in)), {});
        const auto g0 = svg.find("<g class=\"underlay\"");
        ASSERT_NE(g0, std::string::npos);
        const std::string group = svg.substr(g0, svg.find("</g>", g0) - g0);
        std::size_t rects = 0;
        double right = 0, bottom = 0;
        for (auto at = group.find("<rect"); at != std::string::npos;
             at = group.find("<rect", at + 1)) {
            ++rects;
            double x = 0, y = 0, w = 0, h = 0;
            std::sscanf(group.c_str() + at,
                        "<rect x=\"%lf\" y=\"%lf\" width=\"%lf\" height=\"%lf\"", &x, &y, &w, &h);
            right = std::max(right, x + w);
            bottom = std::max(bottom, y + h);
        }
        EXPECT_EQ(rects, 16u * static_cast<std::size_t>(map.cols() * map.rows()));
        EXPECT_NEAR(right, lu.mapX + lu.mapW, 1e-3);
        EXPECT_NEAR(bottom, lu.mapY + lu.mapH, 1e-3);
        fs::remove_all(dir);
    }
    MapPlane coarse = plane;
    coarse.pixelM = plane.pixelM * 2;
    coarse.extentU = map.cols() * plane.pixelM;
    coarse.extentV = map.rows() * plane.pixelM;
    withUnder.underlay.emplace(coarse);
    EXPECT_THROW(layoutMapFigure(map, withUnder), ValueError);
    // A plane whose u points down x (-x to the right): the mapping follows it.
    MapPlane flipped = plane;
    flipped.u = -Eigen::Vector3d::UnitX();
    const MapLayout lf = layoutMapFigure(ScalarMap(flipped), MapFigure{});
    EXPECT_LT(lf.uPerPx, 0);
    EXPECT_NEAR(lf.mmAtX(lf.mapX + 0.5 * lf.cell), flipped.pixelCentre(0, 0).x() * 1e3, 1e-9);
}

TEST(MapFigure, PngHasTheMapWhereTheLayoutSaysAndItsBarAxesAndTitle) {
    const fs::path dir = tempDir("png");
    const MapPlane plane = testPlane();
    ScalarMap map(plane);
    for (int c = 0; c < map.cols(); ++c)
        for (int r = 0; r < map.rows(); ++r) map.set(c, r, 0.0);
    map.set(19, 11, 10.0);  // the one hot pixel (white)
    MapFigure fig;
    fig.title = "test: avc/accumulate, raster";
    const double scale = 1.5;
    writeMapFigurePng(dir / "m.png", map, fig, scale);
    const MapLayout l = layoutMapFigure(map, fig, scale);
    const Rgb img = readPng(dir / "m.png");
    ASSERT_FALSE(img.px.empty());
    EXPECT_EQ(img.w, static_cast<int>(std::ceil(l.width)));
    EXPECT_EQ(img.h, static_cast<int>(std::ceil(l.height)));

    // The white pixels inside the map: their centre, in mm through the layout, is the hot
    // pixel's world position (within a quarter of a map pixel).
    double sx = 0, sy = 0, n = 0;
    for (int y = static_cast<int>(l.mapY) + 2; y < static_cast<int>(l.mapY + l.mapH) - 2; ++y) {
        for (int x = static_cast<int>(l.mapX) + 2; x < static_cast<int>(l.mapX + l.mapW) - 2; ++x) {
            const unsigned char* p = img.at(x, y);
            if (p[0] > 240 && p[1] > 240 && p[2] > 240) {
                sx += x + 0.5;
                sy += y + 0.5;
                ++n;
            }
        }
    }
    ASSERT_GT(n, 0);
    EXPECT_NEAR(n, l.cell * l.cell, 4 * l.cell);  // one map pixel's square
    const Eigen::Vector3d hot = plane.pixelCentre(19, 11) * 1e3;
    EXPECT_NEAR(l.mmAtX(sx / n), hot.x(), 0.5);
    EXPECT_NEAR(l.mmAtY(sy / n), hot.z(), 0.5);
    // Elsewhere the map is black (value 0), edge to edge.
    EXPECT_LT(img.lum(static_cast<int>(l.mapX + 3), static_cast<int>(l.mapY + l.mapH - 3)), 10);

    // The colour bar: black at the bottom, white at the top, brightening upwards.
    const int bx = static_cast<int>(l.bar.x + l.bar.w / 2);
    int last = -1, rises = 0;
    for (int y = static_cast<int>(l.bar.y + l.bar.h) - 3; y > static_cast<int>(l.bar.y) + 3;
         y -= 4) {
        const int v = img.at(bx, y)[0] + img.at(bx, y)[1] + img.at(bx, y)[2];
        EXPECT_GE(v, last - 3) << y;
        rises += v > last;
        last = v;
    }
    EXPECT_GT(rises, 20);
    EXPECT_LT(img.lum(bx, static_cast<int>(l.bar.y + l.bar.h) - 3), 30);
    EXPECT_GT(img.lum(bx, static_cast<int>(l.bar.y) + 3), 225);

    // Drawn (dark) pixels in the axes' band under the map, the v axis' band left of it, the
    // colour bar's labels right of it and the title's band above it.
    const auto dark = [&](double x0, double y0, double x1, double y1) {
        int count = 0;
        for (int y = static_cast<int>(y0); y < static_cast<int>(y1); ++y)
            for (int x = static_cast<int>(x0); x < static_cast<int>(x1); ++x)
                count += img.lum(x, y) < 100;
        return count;
    };
    EXPECT_GT(dark(l.mapX, l.mapY + l.mapH + 2, l.mapX + l.mapW, l.height), 200);
    EXPECT_GT(dark(0, l.mapY, l.mapX - 2, l.mapY + l.mapH), 200);
    EXPECT_GT(dark(l.bar.x + l.bar.w + 2, l.mapY, l.width, l.mapY + l.mapH), 200);
    EXPECT_GT(dark(0, 0, l.width, l.mapY - 4), 100);
    fs::remove_all(dir);
}

/// A block of tissue (0 HU) under air (-1000 HU) whose skin lies at y = 5 mm + 0.2 x, with bone
/// (1000 HU) from y = 25 mm for x > 0, at 1 mm voxels: x -30..34, y -2..40, z -20..16 mm.
volume::Volume tiltedSkin() {
    volume::initialize();
    auto grid = openvdb::FloatGrid::create(-1000.0f);
    grid->setName("scan");
    grid->setTransform(openvdb::math::Transform::createLinearTransform(1e-3));
    auto acc = grid->getAccessor();
    for (int i = -30; i <= 34; ++i) {
        for (int j = -2; j <= 40; ++j) {
            for (int k = -20; k <= 16; ++k) {
                const double skin = 5 + 0.2 * i;  // mm
                double v = std::clamp(-1000 + 500 * (j - skin + 1), -1000.0, 0.0);
                if (i > 0 && j >= 25) v = 1000;
                acc.setValueOn({i, j, k}, static_cast<float>(v));
            }
        }
    }
    volume::Volume vol;
    vol.grid = grid;
    vol.info.valueUnits = "HU";
    return vol;
}

// The demo's underlay: a skin 22.5-32.8 um under the map's plane (the iso-surface between the
// air and the fat voxels of a phantom converted at 0.5 mm). Its bar once read "0.024 ... 0.032"
// against "skin depth (mm)", which reads as metres labelled mm; a sub-millimetre range now reads
// in micrometres, and each tick's number is the underlay's value (in the label's unit) at the
// tick's height on the bar. A millimetre range stays in mm.
TEST(MapUnderlay, TheUnderlayBarsNumbersAndUnitAgree) {
    const MapPlane plane = testPlane();
    for (const double lo : {0.0225, 5.0}) {
        const double span = lo < 1 ? 0.0103 : 10.0;
        ScalarMap depth(plane);
        for (int c = 0; c < depth.cols(); ++c)
            for (int r = 0; r < depth.rows(); ++r)
                depth.set(c, r, lo + span * c / (depth.cols() - 1));
        MapFigure fig;
        fig.underlay.emplace(plane);
        fig.underlay->map = depth;  // skin depth, mm (skinDepthMap's unit)
        const MapLayout l = layoutMapFigure(ScalarMap(plane), fig, 1.0);
        ASSERT_TRUE(l.underBar.has_value());
        const bool micro = lo < 1;
        const double perUnit = micro ? 1e-3 : 1.0;  // mm per unit of the label
        int ticks = 0;
        for (const FigureText& t : l.texts) {
            if (t.cls == "underlay") {
                EXPECT_EQ(t.body, micro ? "skin depth (\u00b5m)" : "skin depth (mm)");
            }
            if (t.cls != "underlay-tick") continue;
            ++ticks;
            const double v = std::stod(t.body) * perUnit;  // mm
            EXPECT_GE(v, l.underLo - 1e-9) << t.body;
            EXPECT_LE(v, l.underHi + 1e-9) << t.body;
            // Ticks are placed at y = bar bottom - (v - lo) / (hi - lo) * height (+4 baseline).
            const FigureBar& b = *l.underBar;
            const double y = b.y + b.h - (v - l.underLo) / (l.underHi - l.underLo) * b.h + 4;
            EXPECT_NEAR(t.y, y, 1e-6 * b.h) << t.body;
        }
        EXPECT_GE(ticks, 3) << lo;
        EXPECT_NEAR(l.underLo, lo, 1e-12);
        EXPECT_NEAR(l.underHi, lo + span, 1e-12);
    }
}

TEST(MapUnderlay, SkinDepthAndMipOfATiltedSkinAndItsGreyUnderTheMap) {
    const volume::Volume vol = tiltedSkin();
    auto scene = Scene::fromVolume(vol);
    const MapPlane plane = testPlane();
    const Eigen::Vector3d press = Eigen::Vector3d::UnitY();
    const ScalarMap depth = skinDepthMap(scene->surfaces(), plane, press, 0.06);
    for (int c = 0; c < depth.cols(); ++c) {
        for (int r = 0; r < depth.rows(); ++r) {
            const double x = plane.pixelCentre(c, r).x() * 1e3;
            EXPECT_NEAR(depth.at(c, r), 5 + 0.2 * x, 0.3) << c << " " << r;
        }
    }
    const ScalarMap mip = mipMap(vol, plane, press, 0.06);
    for (int c = 0; c < mip.cols(); ++c) {
        const double x = plane.pixelCentre(c, 5).x() * 1e3;
        if (x > 2) {
            EXPECT_NEAR(mip.at(c, 5), 1000, 1) << x;
        } else if (x < -2) {
            EXPECT_NEAR(mip.at(c, 5), 0, 1) << x;
        }
    }
    EXPECT_THROW(skinDepthMap(scene->surfaces(), plane, Eigen::Vector3d::UnitX(), 0.06),
                 ValueError);  // along the plane

    // Drawn under an empty map: the grey falls from light (the nearest skin, at the left) to dark
    // (the deepest, at the right) along every row, within its range of greys (white and black
    // stay the map's), and its bar says so.
    const fs::path dir = tempDir("underlay");
    MapFigure fig;
    fig.title = "underlay";
    fig.underlay.emplace(plane);
    fig.underlay->map = depth;
    fig.underlay->brightLow = true;
    const ScalarMap empty(plane);
    writeMapFigurePng(dir / "u.png", empty, fig, 1.0);
    const MapLayout l = layoutMapFigure(empty, fig, 1.0);
    const Rgb img = readPng(dir / "u.png");
    ASSERT_FALSE(img.px.empty());
    ASSERT_TRUE(l.underBar.has_value());
    for (int r : {1, 7, 13}) {
        const int y = static_cast<int>(l.mapY + (depth.rows() - 1 - r + 0.5) * l.cell);
        int prev = 256;
        for (int c = 0; c < depth.cols(); ++c) {
            const int x = static_cast<int>(l.mapX + (c + 0.5) * l.cell);
            const unsigned char* p = img.at(x, y);
            EXPECT_EQ(p[0], p[1]);  // grey
            EXPECT_EQ(p[1], p[2]);
            EXPECT_LT(p[0], prev) << "row " << r << " col " << c;
            prev = p[0];
        }
    }
    const int y0 = static_cast<int>(l.mapY + 0.5 * l.cell);
    const int light = static_cast<int>(std::lround(255 * kUnderlayGreyHi));
    const int dark = static_cast<int>(std::lround(255 * kUnderlayGreyLo));
    EXPECT_NEAR(img.lum(static_cast<int>(l.mapX + 0.5 * l.cell), y0), light, 6);
    EXPECT_NEAR(img.lum(static_cast<int>(l.mapX + l.mapW - 0.5 * l.cell), y0), dark, 6);
    const int ubx = static_cast<int>(l.underBar->x + l.underBar->w / 2);
    // The bar runs from the shallowest (bottom, light) to the deepest (top, dark).
    EXPECT_NEAR(img.lum(ubx, static_cast<int>(l.underBar->y + l.underBar->h) - 3), light, 6);
    EXPECT_NEAR(img.lum(ubx, static_cast<int>(l.underBar->y) + 3), dark, 6);
    fs::remove_all(dir);
}

TEST(MapFigure, RefusesBadInputsAndLeavesNothingBehind) {
    const fs::path dir = tempDir("errors");
    const MapPlane plane = testPlane();
    ScalarMap map(plane);
    map.set(1, 1, 3.0);
    EXPECT_THROW(layoutMapFigure(map, MapFigure{}, 0.0), ValueError);
    MapFigure bad;
    bad.mapOpacity = 0;
    EXPECT_THROW(layoutMapFigure(map, bad, 1.0), ValueError);
    MapPlane other = plane;
    other.centre.x() += 0.001;
    MapFigure foreign;
    foreign.underlay.emplace(other);
    EXPECT_THROW(writeMapFigurePng(dir / "f.png", map, foreign), ValueError);
    EXPECT_THROW(writeMapSvg(dir / "f.svg", map, foreign), ValueError);
    for (const char* name : {"m.png", "m.svg"}) {
        const fs::path path = dir / "missing" / name;
        try {
            if (fs::path(name).extension() == ".png") {
                writeMapFigurePng(path, map);
            } else {
                writeMapSvg(path, map);
            }
            FAIL() << "expected an IoError for " << path;
        } catch (const IoError& e) {
            EXPECT_NE(std::string(e.what()).find(path.string()), std::string::npos) << e.what();
        }
    }
    EXPECT_TRUE(fs::is_empty(dir));
    fs::remove_all(dir);
}

}  // namespace
}  // namespace palp::haptics
