// Maps over the palpated plane: MapPlane pixels, ScalarMap means and gap filling.
#include <gtest/gtest.h>

#include <cmath>
#include <string>

#include "palp/base/error.h"
#include "palp/studies/scalar_map.h"

namespace palp::haptics {
namespace {

TEST(MapPlane, PixelOfAndPixelCentreAreInverse) {
    MapPlane p;
    p.centre = {0.01, 0.002, -0.02};
    p.extentU = 0.03;
    p.extentV = 0.02;
    p.pixelM = 0.002;
    ASSERT_EQ(p.cols(), 15);
    ASSERT_EQ(p.rows(), 10);
    for (int r = 0; r < p.rows(); ++r) {
        for (int c = 0; c < p.cols(); ++c) {
            int cc = -1, rr = -1;
            // Points off the plane along the normal (y) project onto the same pixel.
            ASSERT_TRUE(p.pixelOf(p.pixelCentre(c, r) + Eigen::Vector3d(0, 0.005, 0), cc, rr));
            EXPECT_EQ(cc, c);
            EXPECT_EQ(rr, r);
        }
    }
    int c = 0, r = 0;
    EXPECT_FALSE(p.pixelOf(p.centre + Eigen::Vector3d(0.0151, 0, 0), c, r));
    EXPECT_FALSE(p.pixelOf(p.centre + Eigen::Vector3d(0, 0, -0.0101), c, r));
    // Column 0 is the smallest u (x), row 0 the smallest v (z).
    ASSERT_TRUE(p.pixelOf(p.centre + Eigen::Vector3d(-0.0149, 0, -0.0099), c, r));
    EXPECT_EQ(c, 0);
    EXPECT_EQ(r, 0);
}

TEST(MapPlane, RejectsBadPlanesNamingTheField) {
    MapPlane p;
    p.pixelM = 0;
    EXPECT_THROW(validateMapPlane(p), ValueError);
    p = MapPlane{};
    p.v = Eigen::Vector3d(1, 0, 0);  // parallel to u
    try {
        validateMapPlane(p);
        FAIL() << "expected a ValueError";
    } catch (const ValueError& e) {
        EXPECT_NE(std::string(e.what()).find("u . v"), std::string::npos) << e.what();
    }
    p = MapPlane{};
    p.extentU = 1.0;
    p.pixelM = 1e-4;  // 10000 pixels
    EXPECT_THROW(validateMapPlane(p), ValueError);
}

TEST(ScalarMap, MeansPerPixelAndFillsGaps) {
    MapPlane p;
    p.extentU = p.extentV = 0.004;
    p.pixelM = 0.001;  // 4 x 4
    ScalarMap m(p);
    const Eigen::Vector3d a = p.pixelCentre(1, 2);
    m.add(a, 2.0);
    m.add(a + Eigen::Vector3d(0.0004, 0, 0), 4.0);
    m.add(a, std::nan(""));                  // ignored
    m.add(Eigen::Vector3d(1, 0, 0), 100.0);  // outside: ignored
    EXPECT_DOUBLE_EQ(m.at(1, 2), 3.0);
    EXPECT_EQ(m.count(1, 2), 2u);
    EXPECT_TRUE(std::isnan(m.at(0, 0)));
    double lo = 0, hi = 0;
    m.range(lo, hi);
    EXPECT_DOUBLE_EQ(lo, 3.0);
    EXPECT_DOUBLE_EQ(hi, 3.0);
    m.fillGaps(1);  // the 8 neighbours of (1, 2) take its value, the rest stays empty
    int filled = 0;
    for (int r = 0; r < 4; ++r)
        for (int c = 0; c < 4; ++c) filled += std::isfinite(m.at(c, r)) ? 1 : 0;
    EXPECT_EQ(filled, 9);
    EXPECT_DOUBLE_EQ(m.at(0, 3), 3.0);
    EXPECT_TRUE(std::isnan(m.at(3, 0)));
    m.fillGaps(10);
    EXPECT_EQ(m.finiteValues().size(), 16u);
}

}  // namespace
}  // namespace palp::haptics
