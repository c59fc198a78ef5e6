#include <gtest/gtest.h>

#include <chrono>
#include <cmath>
#include <random>
#include <vector>

#include "alloc_counter.h"
#include "palp/base/error.h"
#include "palp/kernels/trilinear.h"
#include "palp/kernels/volume_ray.h"
#include "ray_test_shapes.h"

namespace {

using namespace palp::kernels;
using palp::test::kVoxel;

FirstHitParams hitParams() {
    FirstHitParams p;
    p.threshold = palp::test::kIso;
    p.step = 0.25e-3;
    return p;
}

Eigen::Vector3d randomUnit(std::mt19937& rng) {
    std::normal_distribution<double> n;
    return Eigen::Vector3d(n(rng), n(rng), n(rng)).normalized();
}

// Fires rays from random points on a sphere of radius @p r0 around @p c towards random points
// within @p aim of c and compares the volume first-hit with the exact hit.
template <class Shape>
void checkShape(const Shape& shape, const openvdb::FloatGrid::Ptr& grid, const Eigen::Vector3d& c,
                double r0, double aim, int rays, double tolVoxels) {
    const VolumeView view(grid);
    std::mt19937 rng(7);
    int hits = 0;
    FirstHitParams p = hitParams();
    for (int n = 0; n < rays; ++n) {
        const Eigen::Vector3d o = c + r0 * randomUnit(rng);
        const Eigen::Vector3d target = c + aim * randomUnit(rng);
        const Eigen::Vector3d d = (target - o).normalized();
        const double exact = shape.hit(o, d);
        const double len = 2 * r0;
        const RayHit h = firstHit(view, o, d, len, p);
        if (!std::isfinite(exact) || exact > len) {
            EXPECT_FALSE(h.hit);
            continue;
        }
        ASSERT_TRUE(h.hit) << "ray " << n;
        ++hits;
        EXPECT_NEAR(h.t, exact, tolVoxels * kVoxel) << "ray " << n;
        // Skipping empty blocks never changes a result.
        p.skipEmpty = false;
        const RayHit h2 = firstHit(view, o, d, len, p);
        p.skipEmpty = true;
        EXPECT_EQ(h2.hit, h.hit);
        EXPECT_FLOAT_EQ(h2.t, h.t);
        // Accumulate with a step sigma (1e6 / m from the iso value on, tau_stop 1) stops 1 um past
        // the first hit.
        AccumulateParams ap;
        ap.sigma = TransferFunction::step(palp::test::kIso, 1e6f);
        ap.tauStop = 1.0;
        ap.reportFirstHit = true;
        ap.firstHitThreshold = palp::test::kIso;
        const AccumulateHit a = accumulate(view, o, d, len, ap);
        ASSERT_TRUE(a.stopped);
        EXPECT_NEAR(a.t, h.t + 1e-6, 0.02 * kVoxel);
        EXPECT_TRUE(a.firstHit);
        EXPECT_NEAR(a.firstHitT, h.t, 1e-3 * kVoxel);
        EXPECT_NEAR(a.integral, 1.0, 1e-6);
    }
    EXPECT_GT(hits, rays / 3);
}

TEST(VolumeRay, PlaneFirstHitWithinAVoxelFraction) {
    const palp::test::Plane plane{Eigen::Vector3d(0.2, -0.3, 1.0).normalized(), 0.7e-3};
    auto grid = palp::test::shapeVolume([&](const Eigen::Vector3d& x) { return plane.sdf(x); },
                                        {-40, -40, -40}, {40, 40, 40});
    const Eigen::Vector3d c(0, 0, 0);
    checkShape(plane, grid, c, 8e-3, 4e-3, 200, 0.05);
}

TEST(VolumeRay, SphereFirstHitWithinAVoxelFraction) {
    const palp::test::Sphere s{Eigen::Vector3d(0.13e-3, -0.21e-3, 0.07e-3), 6e-3};
    auto grid = palp::test::shapeVolume([&](const Eigen::Vector3d& x) { return s.sdf(x); },
                                        {-20, -20, -20}, {20, 20, 20});
    checkShape(s, grid, s.centre, 9.5e-3, 4e-3, 300, 0.05);
}

TEST(VolumeRay, BoxFirstHitWithinAVoxelFraction) {
    const palp::test::Box box{Eigen::Vector3d(0.1e-3, 0.2e-3, -0.3e-3),
                              Eigen::Vector3d(5e-3, 4e-3, 3.5e-3)};
    auto grid = palp::test::shapeVolume([&](const Eigen::Vector3d& x) { return box.sdf(x); },
                                        {-20, -20, -20}, {20, 20, 20});
    const VolumeView view(grid);
    // Rays towards each face, tilted up to ~15 degrees, landing at least 1.5 mm from its edges.
    std::mt19937 rng(3);
    std::uniform_real_distribution<double> u(-1, 1);
    int n = 0;
    for (int axis = 0; axis < 3; ++axis)
        for (int sign : {-1, 1})
            for (int k = 0; k < 30; ++k) {
                Eigen::Vector3d target = box.centre;
                for (int a = 0; a < 3; ++a)
                    target[a] += a == axis ? sign * box.half[a] : u(rng) * (box.half[a] - 1.5e-3);
                Eigen::Vector3d d = -sign * Eigen::Vector3d::Unit(axis);
                d +=
                    0.25 * Eigen::Vector3d(u(rng), u(rng), u(rng))
                               .cwiseProduct(Eigen::Vector3d::Ones() - Eigen::Vector3d::Unit(axis));
                d.normalize();
                const Eigen::Vector3d o = target - 3e-3 * d;
                const double exact = box.hit(o, d);
                ASSERT_NEAR(exact, 3e-3, 1e-9);
                const RayHit h = firstHit(view, o, d, 10e-3, hitParams());
                ASSERT_TRUE(h.hit);
                EXPECT_NEAR(h.t, exact, 0.05 * kVoxel)
                    << "axis " << axis << " sign " << sign << " k " << k;
                ++n;
            }
    EXPECT_EQ(n, 180);
}

// The table sampler reproduces trilinear interpolation through an accessor.
TEST(VolumeRay, ViewSamplerMatchesAccessor) {
    const palp::test::Sphere s{Eigen::Vector3d(0, 0, 0), 5e-3};
    auto grid = palp::test::shapeVolume([&](const Eigen::Vector3d& x) { return s.sdf(x); },
                                        {-16, -16, -16}, {16, 16, 16});
    const VolumeView view(grid);
    const auto acc = grid->getConstAccessor();
    std::mt19937 rng(5);
    std::uniform_real_distribution<double> u(-30, 30);
    for (int n = 0; n < 5000; ++n) {
        const double x = u(rng), y = u(rng), z = u(rng);
        EXPECT_NEAR(view.sampleIndex(x, y, z), sampleIndex(acc, openvdb::Vec3d(x, y, z)), 1e-3);
    }
}

// The marcher's fast paths (padded 9^3 blocks, truncation floor, block DDA skipping, corner
// cache in the refinement) against a plain march through an accessor on a grid that has noise
// across many leaf borders, a constant active tile, inactive background and empty blocks: the
// first lattice sample at or above the threshold brackets palp's hit.
TEST(VolumeRay, FirstHitMatchesAccessorMarchOnANoisyGrid) {
    auto grid = openvdb::FloatGrid::create(-1000.0f);
    grid->setTransform(openvdb::math::Transform::createLinearTransform(kVoxel));
    std::mt19937 rng(11);
    std::uniform_real_distribution<float> noise(0.0f, 400.0f);
    auto acc = grid->getAccessor();
    for (int x = -20; x < 20; ++x)
        for (int y = -20; y < 20; ++y)
            for (int z = -12; z < 12; ++z)
                if ((x * 7 + y * 3 + z) % 5 != 0) acc.setValue(openvdb::Coord(x, y, z), noise(rng));
    grid->fill(openvdb::CoordBBox(openvdb::Coord(128, 0, 0), openvdb::Coord(255, 127, 127)), 500.0f,
               true);
    const VolumeView view(grid);
    const auto cacc = grid->getConstAccessor();
    std::uniform_real_distribution<double> u(-1, 1);
    FirstHitParams p = hitParams();
    p.threshold = 240;
    int hits = 0, checked = 0;
    for (int n = 0; n < 600; ++n) {
        const Eigen::Vector3d o =
            n % 3 == 0 ? Eigen::Vector3d(u(rng) * 12e-3, u(rng) * 12e-3, u(rng) * 8e-3)
                       : Eigen::Vector3d(40e-3 + u(rng) * 30e-3, u(rng) * 30e-3, u(rng) * 30e-3);
        const Eigen::Vector3d d = randomUnit(rng);
        const double len = 0.5 * (1 + u(rng)) * 40e-3;
        const RayHit h = firstHit(view, o, d, len, p);
        const auto kLast = static_cast<int>(std::ceil(len / p.step - 1e-9));
        int kHit = -1;
        for (int k = 0; k <= kLast && kHit < 0; ++k) {
            const double t = std::min(k * p.step, len);
            const Eigen::Vector3d w = o + t * d;
            const openvdb::Vec3d i = grid->worldToIndex(openvdb::Vec3d(w.x(), w.y(), w.z()));
            if (sampleIndex(cacc, i) >= p.threshold) kHit = k;
        }
        ++checked;
        ASSERT_EQ(h.hit, kHit >= 0) << "ray " << n;
        if (kHit < 0) {
            EXPECT_FLOAT_EQ(h.t, static_cast<float>(len));
            continue;
        }
        ++hits;
        const double t1 = std::min(kHit * p.step, len),
                     t0 = kHit > 0 ? std::min((kHit - 1) * p.step, len) : 0.0;
        EXPECT_GE(h.t, t0 - 1e-9) << "ray " << n;
        EXPECT_LE(h.t, t1 + 1e-9) << "ray " << n;
        // And skipping never changes it.
        FirstHitParams q = p;
        q.skipEmpty = false;
        EXPECT_FLOAT_EQ(firstHit(view, o, d, len, q).t, h.t) << "ray " << n;
    }
    EXPECT_EQ(checked, 600);
    EXPECT_GT(hits, 60);  // both outcomes are exercised
    EXPECT_LT(hits, 540);
}

// The AVX2 lockstep bundle path against the scalar path (the reference) and against single-ray
// firstHit(): bit-identical hits on the noisy grid (many leaf borders, a constant tile, skipped
// blocks), for bundles of 2 to 64 rays of random positions, directions and lengths, with and
// without skipping, including degenerate rays that end before any run.
TEST(VolumeRay, BundleSimdMatchesScalarBitForBit) {
    auto grid = openvdb::FloatGrid::create(-1000.0f);
    grid->setTransform(openvdb::math::Transform::createLinearTransform(kVoxel));
    std::mt19937 rng(13);
    std::uniform_real_distribution<float> noise(0.0f, 400.0f);
    auto acc = grid->getAccessor();
    for (int x = -24; x < 24; ++x)
        for (int y = -20; y < 20; ++y)
            for (int z = -12; z < 12; ++z)
                if ((x * 5 + y * 3 + z) % 7 != 0)  // x >= 0: long runs that seldom cross
                    acc.setValue(openvdb::Coord(x, y, z), x < 0 ? noise(rng) : 0.66f * noise(rng));
    grid->fill(openvdb::CoordBBox(openvdb::Coord(64, 0, 0), openvdb::Coord(127, 63, 63)), 500.0f,
               true);
    const VolumeView view(grid);
    std::uniform_real_distribution<double> u(-1, 1);
    std::uniform_int_distribution<int> rays(2, kMaxBundleRays);
    FirstHitParams simd = hitParams();
    simd.threshold = 250;
    int hits = 0, misses = 0, lanes = 0;
    for (int frame = 0; frame < 300; ++frame) {
        RayBundle b;
        b.count = rays(rng);
        b.valid = true;
        for (int r = 0; r < b.count; ++r) {
            const auto i = static_cast<std::size_t>(r);
            const Eigen::Vector3d o =
                r % 2 == 0
                    ? Eigen::Vector3d(u(rng) * 14e-3, u(rng) * 12e-3, u(rng) * 8e-3)
                    : Eigen::Vector3d(30e-3 + u(rng) * 20e-3, u(rng) * 20e-3, u(rng) * 20e-3);
            Eigen::Vector3d d = randomUnit(rng);
            if (r % 23 == 5) d.setZero();  // degenerate: no hit, no run
            b.ox[i] = static_cast<float>(o.x());
            b.oy[i] = static_cast<float>(o.y());
            b.oz[i] = static_cast<float>(o.z());
            b.dx[i] = static_cast<float>(d.x());
            b.dy[i] = static_cast<float>(d.y());
            b.dz[i] = static_cast<float>(d.z());
            b.length[i] = static_cast<float>((0.5 + 0.5 * u(rng)) * 25e-3);
        }
        simd.skipEmpty = frame % 4 != 3;
        FirstHitParams scalar = simd;
        scalar.simd = false;
        BundleHits hs, hr;
        traceFirstHit(view, b, simd, hs);
        traceFirstHit(view, b, scalar, hr);
        ASSERT_EQ(hs.count, b.count);
        ASSERT_EQ(hr.count, b.count);
        for (int r = 0; r < b.count; ++r) {
            const auto i = static_cast<std::size_t>(r);
            const RayHit one =
                firstHit(view, Eigen::Vector3d(b.ox[i], b.oy[i], b.oz[i]),
                         Eigen::Vector3d(b.dx[i], b.dy[i], b.dz[i]), b.length[i], scalar);
            ASSERT_EQ(hs.hit[i], hr.hit[i]) << "frame " << frame << " ray " << r;
            ASSERT_EQ(hs.t[i], hr.t[i]) << "frame " << frame << " ray " << r;  // bit-equal
            ASSERT_EQ(hr.hit[i], one.hit ? 1 : 0);
            ASSERT_EQ(hr.t[i], one.t);
            (hs.hit[i] ? hits : misses) += 1;
            ++lanes;
        }
    }
    EXPECT_GT(hits, lanes / 10);  // both outcomes, many times
    EXPECT_GT(misses, lanes / 10);
}

// Surface Sobel over real rays: on a tilted plane the ray length is linear in the offset, so the
// stencil returns d L / d s = -(n.t) / (n.d) exactly (up to first-hit accuracy).
TEST(VolumeRay, SurfaceSobelOfRayLengthOnATiltedPlane) {
    const palp::test::Plane plane{Eigen::Vector3d(0.3, 0.1, 1.0).normalized(), -3e-3};
    auto grid = palp::test::shapeVolume([&](const Eigen::Vector3d& x) { return plane.sdf(x); },
                                        {-24, -24, -40}, {24, 24, 8});
    const VolumeView view(grid);
    BundleParams bp;
    bp.surfaceOffset = 1e-3;
    RayBundle b;
    const Eigen::Vector3d d(0, 0, -1);
    ASSERT_TRUE(generateBundle(Eigen::Vector3d(0.1e-3, -0.2e-3, 0), d, Eigen::Vector3d(1, 0, 0),
                               Eigen::Vector3d(0, 1, 0), bp, b));
    BundleHits hits;
    traceFirstHit(view, b, hitParams(), hits);
    std::vector<double> len(static_cast<std::size_t>(b.count));
    for (int r = 0; r < b.count; ++r) {
        ASSERT_TRUE(hits.hit[static_cast<std::size_t>(r)]);
        len[static_cast<std::size_t>(r)] = hits.t[static_cast<std::size_t>(r)];
    }
    const auto g = surfaceSobel(b, len);
    EXPECT_NEAR(g.g1, -plane.n.dot(b.t1) / plane.n.dot(d), 2e-3);
    EXPECT_NEAR(g.g2, -plane.n.dot(b.t2) / plane.n.dot(d), 2e-3);
}

// A known edge: a hard layer 3 mm deep for x < 0.25 mm and 6 mm deep beyond. The surface
// stencil at the edge sees (L2 - L1) / (2 h) along t1 = +x, zero along t2.
TEST(VolumeRay, SurfaceSobelAtAKnownEdge) {
    openvdb::initialize();
    auto grid = openvdb::FloatGrid::create(0.0f);
    grid->setTransform(openvdb::math::Transform::createLinearTransform(kVoxel));
    auto acc = grid->getAccessor();
    for (int i = -16; i <= 16; ++i)
        for (int j = -16; j <= 16; ++j)
            for (int k = -30; k <= 4; ++k) {
                const double depth = i <= 0 ? 6.0 : 12.0;  // voxels
                const double sdf = k + depth;              // voxels, negative inside the layer
                const double v = 1000.0 * std::clamp(0.5 - sdf / 4.0, 0.0, 1.0);
                if (v > 0) acc.setValue({i, j, k}, static_cast<float>(v));
            }
    const VolumeView view(grid);
    BundleParams bp;
    bp.surfaceOffset = 1e-3;  // two voxels
    RayBundle b;
    ASSERT_TRUE(generateBundle(Eigen::Vector3d(0.25e-3, 0, 0), Eigen::Vector3d(0, 0, -1),
                               Eigen::Vector3d(1, 0, 0), Eigen::Vector3d(0, 1, 0), bp, b));
    BundleHits hits;
    traceFirstHit(view, b, hitParams(), hits);
    std::vector<double> len(static_cast<std::size_t>(b.count));
    for (int r = 0; r < b.count; ++r)
        len[static_cast<std::size_t>(r)] = hits.t[static_cast<std::size_t>(r)];
    EXPECT_NEAR(len[static_cast<std::size_t>(b.surfaceRay(-1, 0))], 3e-3, 0.05 * kVoxel);
    EXPECT_NEAR(len[static_cast<std::size_t>(b.surfaceRay(1, 1))], 6e-3, 0.05 * kVoxel);
    const auto g = surfaceSobel(b, len);
    EXPECT_NEAR(g.g1, (6e-3 - 3e-3) / (2 * 1e-3), 0.02);
    EXPECT_NEAR(g.g2, 0.0, 1e-3);
    // A stiffness that falls with L (k = 1 / L) has the opposite sign: the edge pushes toward -x.
    std::vector<double> k(len.size());
    for (std::size_t r = 0; r < k.size(); ++r) k[r] = 1.0 / len[r];
    EXPECT_LT(surfaceSobel(b, k).g1, 0.0);
}

TEST(VolumeRay, NoHeapAllocationPerFrame) {
    const palp::test::Sphere s{Eigen::Vector3d(0, 0, 0), 5e-3};
    auto grid = palp::test::shapeVolume([&](const Eigen::Vector3d& x) { return s.sdf(x); },
                                        {-16, -16, -16}, {16, 16, 16});
    const VolumeView view(grid);
    BundleParams bp;
    bp.ringCount = 8;
    AccumulateParams ap;
    ap.sigma = TransferFunction::step(400.0f, 2000.0f);
    ap.reportFirstHit = true;
    const FirstHitParams fp = hitParams();
    const HitField field(view, fp.threshold);  // set-up
    FirstHitParams withField = fp;
    withField.field = &field;
    RayBundle b;
    BundleHits hits;
    BundleAccumulation acc;
    std::uint64_t total = 0;
    int hitCount = 0;
    const std::uint64_t before = palp::test::allocationCount();
    for (int frame = 0; frame < 200; ++frame) {
        const double a = frame * 0.01;
        const Eigen::Vector3d proxy(8e-3 * std::cos(a), 8e-3 * std::sin(a), 1e-3);
        generateBundle(proxy, -proxy, Eigen::Vector3d(0, 0, 1), Eigen::Vector3d(1, 0, 0), bp, b);
        traceFirstHit(view, b, withField, hits);
        hitCount += hits.hit[0];
        traceFirstHit(view, b, fp, hits);
        traceAccumulate(view, b, ap, acc);
        hitCount += hits.hit[0];
    }
    total = palp::test::allocationCount() - before;
    EXPECT_EQ(total, 0u);
    EXPECT_EQ(hitCount, 400);  // the frames did real work
}

TEST(VolumeRay, DegenerateInputIsANoHitInBoundedTime) {
    const palp::test::Sphere s{Eigen::Vector3d(0, 0, 0), 5e-3};
    auto grid = palp::test::shapeVolume([&](const Eigen::Vector3d& x) { return s.sdf(x); },
                                        {-16, -16, -16}, {16, 16, 16});
    const VolumeView view(grid);
    const FirstHitParams p = hitParams();
    const double nan = std::nan(""), inf = INFINITY;
    const Eigen::Vector3d o(0, 0, 10e-3), d(0, 0, -1);
    const auto start = std::chrono::steady_clock::now();
    EXPECT_FALSE(firstHit(view, o, Eigen::Vector3d::Zero(), 10e-3, p).hit);
    EXPECT_FALSE(firstHit(view, o, Eigen::Vector3d(nan, 0, -1), 10e-3, p).hit);
    EXPECT_FALSE(firstHit(view, Eigen::Vector3d(nan, 0, 0), d, 10e-3, p).hit);
    EXPECT_FALSE(firstHit(view, Eigen::Vector3d(inf, 0, 0), d, 10e-3, p).hit);
    EXPECT_FALSE(firstHit(view, o, d, nan, p).hit);
    EXPECT_FALSE(firstHit(view, o, d, -1.0, p).hit);
    EXPECT_FALSE(firstHit(view, o, d, inf, p).hit);
    const RayHit zero = firstHit(view, o, d, 0.0, p);
    EXPECT_FALSE(zero.hit);
    EXPECT_EQ(zero.t, 0.0f);
    FirstHitParams bad = p;
    bad.step = 0;
    EXPECT_FALSE(firstHit(view, o, d, 10e-3, bad).hit);
    EXPECT_THROW(validateFirstHitParams(bad), palp::ValueError);
    // Huge lengths: finite answer, cut at kMaxSamplesPerRay samples.
    const RayHit huge = firstHit(view, o, d, 1e30, p);
    EXPECT_TRUE(huge.hit);
    EXPECT_NEAR(huge.t, 5e-3, 0.05 * kVoxel);
    const RayHit away = firstHit(view, o, Eigen::Vector3d(0, 0, 1), 1e30, p);
    EXPECT_FALSE(away.hit);
    EXPECT_FLOAT_EQ(away.t, static_cast<float>(p.step * kMaxSamplesPerRay));
    // Huge coordinates.
    EXPECT_FALSE(firstHit(view, Eigen::Vector3d(1e300, 0, 0), d, 1e30, p).hit);
    // Empty grid.
    auto empty = openvdb::FloatGrid::create(-1000.0f);
    empty->setTransform(openvdb::math::Transform::createLinearTransform(kVoxel));
    const VolumeView ev(empty);
    EXPECT_TRUE(ev.empty());
    EXPECT_FALSE(firstHit(ev, o, d, 10e-3, p).hit);
    AccumulateParams ap;
    ap.sigma = TransferFunction::step(0.0f, 1e3f);
    EXPECT_FALSE(accumulate(ev, o, d, 10e-3, ap).stopped);
    EXPECT_FALSE(accumulate(view, o, Eigen::Vector3d(nan, 0, 0), 10e-3, ap).stopped);
    // Invalid bundle: no rays.
    RayBundle b;
    generateBundle(o, Eigen::Vector3d::Zero(), d, d, BundleParams{}, b);
    BundleHits hits;
    traceFirstHit(view, b, p, hits);
    EXPECT_EQ(hits.count, 0);
    const double seconds =
        std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
    EXPECT_LT(seconds, 10.0);  // a generous bound against endless loops, not a timing claim
    // Set-up errors.
    EXPECT_THROW(VolumeView(openvdb::FloatGrid::ConstPtr()), palp::ValueError);
    auto aniso = openvdb::FloatGrid::create(0.0f);
    openvdb::math::Mat4d m = openvdb::math::Mat4d::identity();
    m.preScale(openvdb::Vec3d(1e-3, 2e-3, 1e-3));
    aniso->setTransform(openvdb::math::Transform::createLinearTransform(m));
    EXPECT_THROW(VolumeView{aniso}, palp::ValueError);
}

TEST(VolumeRay, TransferFunctionIntegral) {
    const std::array<std::array<float, 2>, 3> nodes{
        {{0.0f, 0.0f}, {100.0f, 10.0f}, {200.0f, 10.0f}}};
    const TransferFunction tf(nodes);
    EXPECT_FLOAT_EQ(tf.sigma(-5.0f), 0.0f);
    EXPECT_FLOAT_EQ(tf.sigma(50.0f), 5.0f);
    EXPECT_FLOAT_EQ(tf.sigma(500.0f), 10.0f);
    EXPECT_NEAR(tf.integral(100.0) - tf.integral(0.0), 500.0, 1e-9);
    EXPECT_NEAR(tf.integral(300.0) - tf.integral(100.0), 2000.0, 1e-9);
    EXPECT_FLOAT_EQ(tf.zeroBelow(), 0.0f);
    const std::array<std::array<float, 2>, 2> bad{{{5.0f, 0.0f}, {1.0f, 1.0f}}};
    EXPECT_THROW(TransferFunction{bad}, palp::ValueError);
}

}  // namespace
