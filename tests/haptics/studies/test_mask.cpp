// Masks over a map plane: IoU, Otsu's threshold, and the tie-aware choice of the largest score.
#include <gtest/gtest.h>

#include <array>
#include <cmath>
#include <numbers>
#include <random>
#include <vector>

#include "palp/base/error.h"
#include "palp/studies/mask.h"

namespace palp::haptics {
namespace {

TEST(Masks, IouOfTwoDiscsMatchesTheLensArea) {
    // Two discs of radius R whose centres are d apart: the lens area is
    // 2 R^2 acos(d / 2R) - (d / 2) sqrt(4 R^2 - d^2).
    MapPlane p;
    p.extentU = p.extentV = 0.08;
    p.pixelM = 0.0002;
    const double R = 0.015, d = 0.01;
    const Mask a = rasterizeMask(
        p, [&](const Eigen::Vector3d& x) { return std::hypot(x.x() - d / 2, x.z()) <= R; });
    const Mask b = rasterizeMask(
        p, [&](const Eigen::Vector3d& x) { return std::hypot(x.x() + d / 2, x.z()) <= R; });
    const double lens = 2 * R * R * std::acos(d / (2 * R)) - d / 2 * std::sqrt(4 * R * R - d * d);
    const double disc = std::numbers::pi * R * R;
    const double expected = lens / (2 * disc - lens);
    EXPECT_NEAR(intersectionOverUnion(a, b), expected, 0.005);
    EXPECT_DOUBLE_EQ(intersectionOverUnion(a, a), 1.0);
    EXPECT_DOUBLE_EQ(intersectionOverUnion(Mask(10, 0), Mask(10, 0)), 1.0);
    EXPECT_THROW(intersectionOverUnion(a, Mask(3, 0)), ValueError);
}

TEST(Masks, OtsuSeparatesTwoLevelsWhateverTheirShare) {
    for (double share : {0.1, 0.3, 0.5, 0.8}) {
        MapPlane p;
        p.extentU = p.extentV = 0.05;
        p.pixelM = 0.001;
        ScalarMap m(p);
        std::mt19937 rng(3);
        std::normal_distribution<double> noise(0, 15);
        Mask truth(static_cast<std::size_t>(m.cols() * m.rows()), 0);
        for (int r = 0; r < m.rows(); ++r) {
            for (int c = 0; c < m.cols(); ++c) {
                const bool in = c < share * m.cols();
                truth[static_cast<std::size_t>(r * m.cols() + c)] = in ? 1 : 0;
                m.set(c, r, (in ? 570 : 300) + noise(rng));
            }
        }
        const double t = otsuThreshold(m);
        EXPECT_GT(t, 350) << share;
        EXPECT_LT(t, 520) << share;
        EXPECT_GT(intersectionOverUnion(thresholdMap(m, t), truth), 0.99) << share;
    }
    MapPlane p;
    ScalarMap flat(p);
    EXPECT_TRUE(std::isnan(otsuThreshold(flat)));  // empty
    flat.set(0, 0, 1);
    flat.set(1, 0, 1);
    EXPECT_TRUE(std::isnan(otsuThreshold(flat)));  // one value
}

TEST(PickLargest, ClearWinnerAlwaysTiesBrokenAtRandomNotByPosition) {
    const std::array<double, 4> clear{300, 300, 420, 301};
    for (std::uint64_t seed = 0; seed < 50; ++seed) EXPECT_EQ(pickLargest(clear, 0.05, seed), 2);
    const std::array<double, 4> tied{300, 300, 300, 300};
    std::array<int, 4> hits{};
    for (std::uint64_t seed = 0; seed < 400; ++seed)
        ++hits[static_cast<std::size_t>(pickLargest(tied, 0.05, seed))];
    for (int h : hits) {
        EXPECT_GT(h, 60);  // each ~100 of 400; a fixed choice would give 400 and 0s
        EXPECT_LT(h, 140);
    }
    const std::array<double, 3> withNan{std::nan(""), 5, 4};
    EXPECT_EQ(pickLargest(withNan, 0.0, 1), 1);
    const std::array<double, 2> allNan{std::nan(""), std::nan("")};
    EXPECT_EQ(pickLargest(allNan, 0.05, 1), -1);
}

}  // namespace
}  // namespace palp::haptics
