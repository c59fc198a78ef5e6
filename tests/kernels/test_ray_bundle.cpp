#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <cmath>
#include <vector>

#include "palp/base/error.h"
#include "palp/kernels/ray_bundle.h"

namespace {

using palp::kernels::BundleParams;
using palp::kernels::RayBundle;

Eigen::Vector3d dirOf(const RayBundle& b, int r) {
    const auto i = static_cast<std::size_t>(r);
    return {b.dx[i], b.dy[i], b.dz[i]};
}
Eigen::Vector3d originOf(const RayBundle& b, int r) {
    const auto i = static_cast<std::size_t>(r);
    return {b.ox[i], b.oy[i], b.oz[i]};
}

TEST(RayBundle, LayoutAndGeometry) {
    BundleParams p;
    p.ringCount = 8;
    p.ringHalfAngle = 0.12;
    p.ringWeightSigma = 0.1;
    p.sobelAngle = 0.04;
    p.surfaceOffset = 0.7e-3;
    RayBundle b;
    const Eigen::Vector3d o(0.01, -0.02, 0.03), d = Eigen::Vector3d(0.3, -0.4, -1.0).normalized();
    ASSERT_TRUE(palp::kernels::generateBundle(o, d * 3.0, Eigen::Vector3d(1, 0, 0),
                                              Eigen::Vector3d(0, 1, 0), p, b));
    EXPECT_EQ(b.count, 25);
    EXPECT_NEAR(b.e1.dot(d), 0, 1e-12);
    EXPECT_NEAR(b.e2.dot(d), 0, 1e-12);
    EXPECT_NEAR(b.e1.dot(b.e2), 0, 1e-12);
    EXPECT_NEAR(b.e1.cross(b.e2).dot(d), 1, 1e-12);  // right-handed
    // Centre ray.
    EXPECT_NEAR((dirOf(b, 0) - d).norm(), 0, 1e-6);
    // Ring: on the cone, equal Gaussian weights, total weight 1.
    double wsum = b.weight[0];
    const double wr = std::exp(-0.12 * 0.12 / (2 * 0.1 * 0.1));
    for (int m = 0; m < 8; ++m) {
        const int r = b.ringBegin + m;
        EXPECT_NEAR(std::acos(std::clamp(dirOf(b, r).dot(d), -1.0, 1.0)), 0.12, 1e-5);
        EXPECT_NEAR(b.weight[static_cast<std::size_t>(r)] / b.weight[0], wr, 1e-6);
        wsum += b.weight[static_cast<std::size_t>(r)];
    }
    EXPECT_NEAR(wsum, 1.0, 1e-6);
    // Spherical stencil: angle i*delta along e1 and j*delta along e2 (projected), origin x_py.
    for (int j = -1; j <= 1; ++j)
        for (int i = -1; i <= 1; ++i) {
            const Eigen::Vector3d dir = dirOf(b, b.sphereRay(i, j));
            EXPECT_NEAR(dir.norm(), 1.0, 1e-6);
            EXPECT_NEAR(std::atan2(dir.dot(b.e1), dir.dot(d)), i * 0.04, 1e-6);
            EXPECT_NEAR(std::atan2(dir.dot(b.e2), dir.dot(d)), j * 0.04, 1e-6);
            EXPECT_NEAR((originOf(b, b.sphereRay(i, j)) - o).norm(), 0, 1e-8);
            // Surface stencil: origin offset h (i t1 + j t2), direction d.
            const Eigen::Vector3d os = originOf(b, b.surfaceRay(i, j));
            EXPECT_NEAR((os - (o + 0.7e-3 * (i * b.t1 + j * b.t2))).norm(), 0, 1e-8);
            EXPECT_NEAR((dirOf(b, b.surfaceRay(i, j)) - d).norm(), 0, 1e-6);
            EXPECT_EQ(b.weight[static_cast<std::size_t>(b.surfaceRay(i, j))] == 0,
                      !(i == 0 && j == 0));
        }
    // Surface frame: orthonormal, t1 along the given tangent.
    EXPECT_NEAR((b.t1 - Eigen::Vector3d::UnitX()).norm(), 0, 1e-12);
    EXPECT_NEAR(b.t1.dot(b.t2), 0, 1e-12);
}

// The Sobel stencil differentiates a linear field exactly.
TEST(RayBundle, SobelExactForLinearFields) {
    BundleParams p;
    p.sobelAngle = 0.05;
    p.surfaceOffset = 0.5e-3;
    RayBundle b;
    const Eigen::Vector3d o(0.02, 0.01, -0.05), d = Eigen::Vector3d(-0.2, 0.9, 0.4).normalized();
    ASSERT_TRUE(palp::kernels::generateBundle(o, d, Eigen::Vector3d(0, 0, 1),
                                              Eigen::Vector3d(1, 0, 0), p, b));
    // k linear in the two stencil angles: spherical Sobel returns the angular derivatives.
    const double a = 300, b1 = 1234.5, b2 = -678.25;
    std::vector<double> k(static_cast<std::size_t>(b.count));
    for (int r = 0; r < b.count; ++r) {
        const Eigen::Vector3d dir = dirOf(b, r);
        const double th1 = std::atan2(dir.dot(b.e1), dir.dot(b.direction));
        const double th2 = std::atan2(dir.dot(b.e2), dir.dot(b.direction));
        k[static_cast<std::size_t>(r)] = a + b1 * th1 + b2 * th2;
    }
    const auto gs = palp::kernels::sphericalSobel(b, k);
    EXPECT_NEAR(gs.g1, b1, 1e-4 * std::fabs(b1));
    EXPECT_NEAR(gs.g2, b2, 1e-4 * std::fabs(b2));
    // k linear in position: surface Sobel returns the tangential gradient.
    const Eigen::Vector3d grad(500.0, -250.0, 125.0);
    for (int r = 0; r < b.count; ++r)
        k[static_cast<std::size_t>(r)] = a + grad.dot(originOf(b, r) - o);
    const auto gt = palp::kernels::surfaceSobel(b, k);
    EXPECT_NEAR(gt.g1, grad.dot(b.t1), 1e-3);
    EXPECT_NEAR(gt.g2, grad.dot(b.t2), 1e-3);
    // Exact arithmetic on a hand-made stencil: k = 2 i - 3 j + 1 at spacing 0.5.
    std::array<double, 9> s{};
    for (int j = -1; j <= 1; ++j)
        for (int i = -1; i <= 1; ++i)
            s[static_cast<std::size_t>((j + 1) * 3 + i + 1)] = 2.0 * i - 3.0 * j + 1;
    const auto g = palp::kernels::sobel3x3(s, 0.5);
    EXPECT_DOUBLE_EQ(g.g1, 4.0);
    EXPECT_DOUBLE_EQ(g.g2, -6.0);
    // Low-pass of a constant is the constant.
    std::vector<double> c(static_cast<std::size_t>(b.count), 7.5);
    EXPECT_NEAR(palp::kernels::lowPass(b, c), 7.5, 1e-6);
}

TEST(RayBundle, DegenerateInputGivesInvalidBundle) {
    BundleParams p;
    RayBundle b;
    const Eigen::Vector3d o(0, 0, 0), t1(1, 0, 0), t2(0, 1, 0);
    const double nan = std::nan("");
    EXPECT_FALSE(palp::kernels::generateBundle(o, Eigen::Vector3d::Zero(), t1, t2, p, b));
    EXPECT_EQ(b.count, 0);
    EXPECT_FALSE(palp::kernels::generateBundle(o, Eigen::Vector3d(nan, 0, 1), t1, t2, p, b));
    EXPECT_FALSE(palp::kernels::generateBundle(Eigen::Vector3d(nan, 0, 0), Eigen::Vector3d(0, 0, 1),
                                               t1, t2, p, b));
    EXPECT_FALSE(palp::kernels::generateBundle(o, Eigen::Vector3d(INFINITY, 0, 1), t1, t2, p, b));
    EXPECT_EQ(b.count, 0);
    // A degenerate tangent frame falls back to (e1, e2) and still gives a valid bundle.
    EXPECT_TRUE(palp::kernels::generateBundle(o, Eigen::Vector3d(0, 0, -1), Eigen::Vector3d::Zero(),
                                              t2, p, b));
    EXPECT_NEAR(b.t1.dot(b.direction), 0, 1e-12);
    // Set-up validation names the field.
    p.ringCount = 100;
    EXPECT_THROW(palp::kernels::validateBundleParams(p), palp::ValueError);
    p.ringCount = 8;
    p.length = -1;
    try {
        palp::kernels::validateBundleParams(p);
        FAIL() << "no throw";
    } catch (const palp::ValueError& e) {
        EXPECT_NE(std::string(e.what()).find("bundle length: expected"), std::string::npos);
    }
}

}  // namespace
