// First-hit skipping inside blocks that cannot be skipped whole, by the view's 4^3 sub-block
// bounds and by a HitField's per-cell bits: the bounds and bits themselves, and
// bit-identical results with and without skipping, scalar and AVX2, with and without a field,
// on volumes built so that thin bone slabs and single hot voxels sit on block and sub-block
// faces, edges and corners, with rays along the axes and nearly parallel to the faces.
#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <random>
#include <vector>

#include "lattice_setup_check.h"  // kernels/src (internal)
#include "palp/base/error.h"
#include "palp/kernels/volume_ray.h"
#include "view_table.h"  // kernels/src (internal)

namespace {

using namespace palp::kernels;

constexpr double kVox = 0.5e-3;
constexpr float kThreshold = 300;

// Soft tissue (40 HU +- 20) in [-16, 31]^3 with a -1000 HU inactive background, 1000 HU slabs one
// voxel thick at x = 3 (inside a block, on a sub-block face), y = 7 (last layer of a block),
// z = 16 (first layer of a block), and hot voxels on block and sub-block corners and edges.
openvdb::FloatGrid::Ptr makeGrid(std::uint32_t seed) {
    auto grid = openvdb::FloatGrid::create(-1000.0f);
    grid->setTransform(openvdb::math::Transform::createLinearTransform(kVox));
    std::mt19937 rng(seed);
    std::uniform_real_distribution<float> tissue(20.0f, 60.0f);
    auto acc = grid->getAccessor();
    for (int x = -16; x < 32; ++x)
        for (int y = -16; y < 32; ++y)
            for (int z = -16; z < 32; ++z) {
                float v = tissue(rng);
                // One voxel thick: the blocks holding a slab have empty sub-blocks beside it.
                if (x == 3 && y < 20) v = 1000;
                if (y == 7 && x >= 8) v = 1000;
                if (z == 16 && x < 0) v = 1000;
                acc.setValue(openvdb::Coord(x, y, z), v);
            }
    const int hot[][3] = {{0, 0, 0},    {4, 4, 4},   {7, 7, 7},     {8, 3, 4},   {-1, 4, 8},
                          {20, 20, 24}, {12, 23, 3}, {-9, -5, -13}, {27, 8, 19}, {15, 0, 12}};
    for (const auto& h : hot) acc.setValue(openvdb::Coord(h[0], h[1], h[2]), 1000.0f);
    return grid;
}

struct Ray {
    Eigen::Vector3d o, d;
    double length;
};

// Random rays in the tissue box; every fifth along an axis (two direction components exactly
// zero), every seventh with one component a hair from zero (nearly parallel to block faces),
// every eleventh starting exactly on a sub-block corner.
std::vector<Ray> makeRays(std::uint32_t seed, int n) {
    std::mt19937 rng(seed);
    std::uniform_real_distribution<double> u(-1, 1);
    std::normal_distribution<double> g;
    std::uniform_int_distribution<int> axis(0, 2), corner(-3, 6);
    std::vector<Ray> rays;
    for (int i = 0; i < n; ++i) {
        Ray r;
        r.o = Eigen::Vector3d(8 + 22 * u(rng), 8 + 22 * u(rng), 8 + 22 * u(rng)) * kVox;
        if (i % 11 == 3)
            r.o = Eigen::Vector3d(4.0 * corner(rng), 4.0 * corner(rng), 4.0 * corner(rng)) * kVox;
        r.d = Eigen::Vector3d(g(rng), g(rng), g(rng)).normalized();
        if (i % 5 == 0) {
            r.d.setZero();
            r.d[axis(rng)] = u(rng) < 0 ? -1 : 1;
        } else if (i % 7 == 0) {
            r.d[axis(rng)] = 1e-7 * u(rng);
        }
        r.length = (0.25 + std::fabs(u(rng))) * 48 * kVox;
        rays.push_back(r);
    }
    return rays;
}

FirstHitParams params(bool skip, bool simd, const HitField* field = nullptr) {
    FirstHitParams p;
    p.threshold = kThreshold;
    p.step = 0.25e-3;
    p.skipEmpty = skip;
    p.simd = simd;
    p.field = field;
    return p;
}

// Rays rays[next .. next + count) as a bundle (advances @p next); @p scale multiplies each
// direction (the set-up normalises it).
template <class Scale>
RayBundle bundleOf(const std::vector<Ray>& rays, std::size_t& next, int count, Scale&& scale) {
    RayBundle b;
    b.count = count;
    b.valid = true;
    for (int r = 0; r < count; ++r, ++next) {
        const auto i = static_cast<std::size_t>(r);
        const Ray& ray = rays[next];
        const double s = scale();
        b.ox[i] = static_cast<float>(ray.o.x());
        b.oy[i] = static_cast<float>(ray.o.y());
        b.oz[i] = static_cast<float>(ray.o.z());
        b.dx[i] = static_cast<float>(ray.d.x() * s);
        b.dy[i] = static_cast<float>(ray.d.y() * s);
        b.dz[i] = static_cast<float>(ray.d.z() * s);
        b.length[i] = static_cast<float>(ray.length);
    }
    return b;
}

}  // namespace

// Every sub-block bound is at least the largest of the 5^3 values its cells interpolate, and
// below the threshold exactly when all of them are (the bound exceeds that maximum by a hair
// only). The test volume holds blocks with both kinds of sub-block, so the march has sub-blocks
// to skip inside blocks it cannot skip.
TEST(VolumeRaySubBlocks, BoundsCoverTheirCellsValues) {
    const VolumeView view(makeGrid(3));
    const auto& tb = detail::viewTable(view);
    ASSERT_NE(tb.subMax, nullptr);
    const std::size_t blocks = tb.data.size();
    int mixed = 0;
    for (std::size_t b = 0; b < blocks; ++b) {
        const float* copy = tb.data[b];
        const auto c = static_cast<std::size_t>(copy - tb.padded) / detail::ViewTable::kPadded;
        int empty = 0;
        for (int s = 0; s < detail::ViewTable::kSubBlocks; ++s) {
            const int x0 = 4 * ((s >> 2) & 1), y0 = 4 * ((s >> 1) & 1), z0 = 4 * (s & 1);
            float mx = -1e30f;
            for (int x = x0; x <= x0 + 4; ++x)
                for (int y = y0; y <= y0 + 4; ++y)
                    for (int z = z0; z <= z0 + 4; ++z) mx = std::max(mx, copy[(x * 9 + y) * 9 + z]);
            const float bound =
                tb.subMax[c * detail::ViewTable::kSubBlocks + static_cast<std::size_t>(s)];
            ASSERT_GE(bound, mx) << "block " << b << " sub-block " << s;
            ASSERT_LE(bound, mx + 1e-3f * (std::fabs(mx) + 2000.0f));
            EXPECT_EQ(bound < kThreshold, mx < kThreshold) << "block " << b << " sub-block " << s;
            empty += bound < kThreshold ? 1 : 0;
        }
        if (tb.maxDilated[b] >= kThreshold && empty > 0) ++mixed;
    }
    EXPECT_GE(mixed, 20);
}

// Single rays: skipping (blocks and sub-blocks) never changes a hit or its t, to the bit; and
// the hit sample is the first lattice sample at or above the threshold as read without skipping.
TEST(VolumeRaySubBlocks, SkippingIsBitIdenticalForSingleRays) {
    const auto grid = makeGrid(5);
    const VolumeView view(grid);
    const HitField field(view, kThreshold);
    int hits = 0, misses = 0;
    const auto rays = makeRays(17, 4000);
    for (std::size_t i = 0; i < rays.size(); ++i) {
        const Ray& r = rays[i];
        const RayHit a = firstHit(view, r.o, r.d, r.length, params(true, false));
        const RayHit b = firstHit(view, r.o, r.d, r.length, params(false, false));
        ASSERT_EQ(a.hit, b.hit) << "ray " << i;
        ASSERT_EQ(a.t, b.t) << "ray " << i;  // bit-equal
        (a.hit ? hits : misses) += 1;
    }
    EXPECT_GT(hits, 600);  // both outcomes, many times
    EXPECT_GT(misses, 600);
}

// The HitField path (its own float lattice, see Lattice in volume_ray.cpp): scalar and AVX2 give
// the same bits; against the block-run path without skipping, the same hits and t within
// 1e-3 voxel (sample positions differ by float rounding, below 1e-3 voxel).
TEST(VolumeRayHitField, SingleRaysAgreeWithTheBlockRuns) {
    const auto grid = makeGrid(5);
    const VolumeView view(grid);
    const HitField field(view, kThreshold);
    const auto rays = makeRays(17, 4000);
    double worst = 0;
    int hits = 0;
    for (std::size_t i = 0; i < rays.size(); ++i) {
        const Ray& r = rays[i];
        const RayHit b = firstHit(view, r.o, r.d, r.length, params(false, false));
        const RayHit c = firstHit(view, r.o, r.d, r.length, params(true, false, &field));
        const RayHit d = firstHit(view, r.o, r.d, r.length, params(true, true, &field));
        ASSERT_EQ(c.hit, d.hit) << "ray " << i;
        ASSERT_EQ(c.t, d.t) << "ray " << i;  // bit-equal
        ASSERT_EQ(c.hit, b.hit) << "ray " << i;
        worst = std::max(worst, std::fabs(static_cast<double>(c.t) - b.t) / kVox);
        hits += c.hit ? 1 : 0;
    }
    EXPECT_LT(worst, 1e-3);
    EXPECT_GT(hits, 600);
}

// Bundles: the AVX2 lockstep path and the scalar path, each with and without skipping, give the
// same bits as single-ray firstHit() without skipping, and a field built for another threshold
// is ignored; the field's scalar and AVX2 lattice marches give the same bits as its single rays
// and the same hits within 1e-3 voxel.
TEST(VolumeRaySubBlocks, BundlesAreBitIdenticalWithAndWithoutSkippingAndSimd) {
    const auto grid = makeGrid(7);
    const VolumeView view(grid);
    const HitField field(view, kThreshold);
    const HitField other(view, kThreshold + 200);
    ASSERT_TRUE(field.matches(view, kThreshold));
    ASSERT_FALSE(other.matches(view, kThreshold));
    const auto rays = makeRays(29, 6000);
    std::mt19937 rng(31);
    std::uniform_int_distribution<int> count(2, kMaxBundleRays);
    std::size_t next = 0;
    int hits = 0, lanes = 0;
    while (next + kMaxBundleRays <= rays.size()) {
        const RayBundle b = bundleOf(rays, next, count(rng), [] { return 1.0; });
        std::array<BundleHits, 7> out;
        traceFirstHit(view, b, params(true, true), out[0]);
        traceFirstHit(view, b, params(false, true), out[1]);
        traceFirstHit(view, b, params(true, false), out[2]);
        traceFirstHit(view, b, params(false, false), out[3]);
        traceFirstHit(view, b, params(true, true, &field), out[4]);
        traceFirstHit(view, b, params(true, false, &field), out[5]);
        traceFirstHit(view, b, params(true, true, &other), out[6]);
        for (int r = 0; r < b.count; ++r) {
            const auto i = static_cast<std::size_t>(r);
            const RayHit one = firstHit(view, Eigen::Vector3d(b.ox[i], b.oy[i], b.oz[i]),
                                        Eigen::Vector3d(b.dx[i], b.dy[i], b.dz[i]), b.length[i],
                                        params(false, false));
            const RayHit lattice = firstHit(view, Eigen::Vector3d(b.ox[i], b.oy[i], b.oz[i]),
                                            Eigen::Vector3d(b.dx[i], b.dy[i], b.dz[i]), b.length[i],
                                            params(true, false, &field));
            for (std::size_t v = 0; v < out.size(); ++v) {
                // Variants 4 and 5 take the field's lattice: bit-equal to its single rays.
                const RayHit& ref = v == 4 || v == 5 ? lattice : one;
                ASSERT_EQ(out[v].count, b.count);
                ASSERT_EQ(out[v].hit[i], ref.hit ? 1 : 0) << "variant " << v << " ray " << r;
                ASSERT_EQ(out[v].t[i], ref.t) << "variant " << v << " ray " << r;  // bit-equal
            }
            ASSERT_EQ(lattice.hit, one.hit) << "ray " << r;
            ASSERT_NEAR(lattice.t, one.t, 1e-3 * kVox) << "ray " << r;
            hits += one.hit ? 1 : 0;
            ++lanes;
        }
    }
    EXPECT_GT(hits, lanes / 10);
    EXPECT_LT(hits, lanes - lanes / 10);
}

// The field path sets up four rays at a time with AVX2 doubles: every field of every ray's
// set-up equals the scalar set-up's (the single-ray path's) bit for bit. Rays of every kind:
// directions of any length (the set-up normalises), tiny components, axis-aligned (taken by the
// scalar set-up), lengths past the sample cap, origins outside the table (clipped or missing
// it), on sub-block corners, and NaN, infinite, zero or negative inputs (refused).
TEST(VolumeRayHitField, VectorRaySetUpIsBitIdenticalToTheScalarOne) {
    const auto grid = makeGrid(11);
    const VolumeView view(grid);
    const HitField field(view, kThreshold);
    const FirstHitParams p = params(true, true, &field);
    const auto rays = makeRays(37, 8000);
    std::mt19937 rng(41);
    std::uniform_real_distribution<double> u(-1, 1);
    std::uniform_int_distribution<int> count(1, kMaxBundleRays), kind(0, 19);
    const float nan = std::numeric_limits<float>::quiet_NaN();
    const float inf = std::numeric_limits<float>::infinity();
    std::size_t next = 0;
    int vectorRays = 0, total = 0;
    while (next + kMaxBundleRays <= rays.size()) {
        // |d| from 1e-3 to 1e3
        RayBundle b = bundleOf(rays, next, count(rng), [&] { return std::pow(10.0, 3 * u(rng)); });
        for (int r = 0; r < b.count; ++r) {
            const auto i = static_cast<std::size_t>(r);
            switch (kind(rng)) {
                case 0:  // far outside the table
                    b.ox[i] = static_cast<float>(0.1 * u(rng));
                    break;
                case 1:  // past the sample cap
                    b.length[i] = 1e3f;
                    break;
                case 2:
                    b.length[i] = 0;
                    break;
                case 3:
                    b.length[i] = -1e-3f;
                    break;
                case 4:
                    b.dy[i] = nan;
                    break;
                case 5:
                    b.oz[i] = inf;
                    break;
                case 6:
                    b.dx[i] = b.dy[i] = b.dz[i] = 0;
                    break;
                case 7:
                    b.length[i] = nan;
                    break;
                case 8:  // a component far below the others
                    b.dz[i] = 1e-30f;
                    break;
                default:
                    break;
            }
        }
        const detail::LatticeSetupCheck c = detail::checkLatticeSetup(view, b, p);
        if (!c.available) GTEST_SKIP() << "no AVX2 on this CPU: the vector set-up is not used";
        EXPECT_EQ(c.mismatches, 0);
        vectorRays += c.vectorRays;
        total += b.count;
    }
    // Most rays take the vector set-up (the axis-aligned and degenerate ones do not).
    EXPECT_GT(vectorRays, total / 2);
    EXPECT_LT(vectorRays, total);
    // A step of 0 or NaN (refused by validateFirstHitParams, but traced without validation):
    // no ray takes the vector set-up, and each is a no-hit equal to its single ray.
    next = 0;
    const RayBundle b = bundleOf(rays, next, 17, [] { return 1.0; });
    for (const double step : {0.0, std::numeric_limits<double>::quiet_NaN()}) {
        FirstHitParams bad = p;
        bad.step = step;
        EXPECT_EQ(detail::checkLatticeSetup(view, b, bad).vectorRays, 0);
        BundleHits out;
        traceFirstHit(view, b, bad, out);
        ASSERT_EQ(out.count, b.count);
        for (int r = 0; r < b.count; ++r) {
            const auto i = static_cast<std::size_t>(r);
            const RayHit one =
                firstHit(view, Eigen::Vector3d(b.ox[i], b.oy[i], b.oz[i]),
                         Eigen::Vector3d(b.dx[i], b.dy[i], b.dz[i]), b.length[i], bad);
            EXPECT_FALSE(one.hit);
            EXPECT_EQ(out.hit[i], 0) << "step " << step << " ray " << r;
            EXPECT_EQ(out.t[i], one.t) << "step " << step << " ray " << r;
        }
    }
}

// A ray grazing a single hot voxel on a sub-block corner: the hit is found (the sub-block next to
// it is not skipped) and lies where the trilinear field first reaches the threshold.
TEST(VolumeRaySubBlocks, HotVoxelOnASubBlockCornerIsHit) {
    auto grid = openvdb::FloatGrid::create(-1000.0f);
    grid->setTransform(openvdb::math::Transform::createLinearTransform(kVox));
    auto acc = grid->getAccessor();
    for (int x = -8; x < 24; ++x)
        for (int y = -8; y < 24; ++y)
            for (int z = -8; z < 24; ++z) acc.setValue(openvdb::Coord(x, y, z), 0.0f);
    acc.setValue(openvdb::Coord(4, 4, 4), 1000.0f);
    const VolumeView view(grid);
    // Along +x through the voxel centre's row: v(x) = 1000 (1 - |x - 4|) near it, so the field
    // reaches 300 at x = 3.3.
    const HitField field(view, kThreshold);
    for (int variant = 0; variant < 4; ++variant) {
        const bool simd = (variant & 1) != 0;
        RayBundle b;
        b.count = 2;
        b.valid = true;
        for (std::size_t i = 0; i < 2; ++i) {
            b.ox[i] = static_cast<float>(-6 * kVox);
            b.oy[i] = static_cast<float>(4 * kVox);
            b.oz[i] = static_cast<float>(4 * kVox);
            b.dx[i] = 1;
            b.dy[i] = 0;
            b.dz[i] = 0;
            b.length[i] = static_cast<float>(20 * kVox);
        }
        BundleHits h;
        traceFirstHit(view, b, params(true, simd, variant >= 2 ? &field : nullptr), h);
        ASSERT_EQ(h.hit[0], 1);
        EXPECT_NEAR(h.t[0], 9.3 * kVox, 0.05 * kVox);
        EXPECT_EQ(h.t[1], h.t[0]);
    }
}

// The field's cell bits: a cell's bit is set when its corner maximum reaches the threshold (what
// lets the march pass over cells whose bit is clear), and only then, up to the bound's hair. Blocks
// with no such cell share the all-clear mask 0, so a block "has a cell" exactly when its mask
// differs from mask 0.
TEST(VolumeRayHitField, CellBitsAndBlockDistancesBoundTheCellsThatCanReachTheThreshold) {
    const VolumeView view(makeGrid(3));
    const HitField field(view, kThreshold);
    const auto& tb = detail::viewTable(view);
    auto cellMax = [&](const float* copy, int x, int y, int z) {
        float mx = -1e30f;
        for (int i = 0; i < 8; ++i)
            mx = std::max(mx, copy[((x + (i >> 2)) * 9 + y + ((i >> 1) & 1)) * 9 + z + (i & 1)]);
        return mx;
    };
    std::vector<const float*> hotCopies;
    int set = 0, clear = 0;
    for (std::size_t b = 0; b < tb.data.size(); ++b) {
        const float* copy = tb.data[b];
        bool any = false;
        for (int x = 0; x < 8; ++x)
            for (int y = 0; y < 8; ++y)
                for (int z = 0; z < 8; ++z) {
                    const float mx = cellMax(copy, x, y, z);
                    const auto l = static_cast<unsigned>((x * 8 + y) * 8 + z);
                    const bool bit = field.cellCanReach(b, l);
                    if (mx >= kThreshold) {
                        ASSERT_TRUE(bit) << b << " " << x << y << z;
                    }
                    if (bit) {
                        ASSERT_GE(mx, kThreshold - 1e-3f * 2000) << b << " " << x << y << z;
                    }
                    any = any || bit;
                    (bit ? set : clear) += 1;
                }
        ASSERT_EQ(any, field.blockMask(b) != field.masks()) << b;
        if (any) hotCopies.push_back(copy);
    }
    std::sort(hotCopies.begin(), hotCopies.end());
    hotCopies.erase(std::unique(hotCopies.begin(), hotCopies.end()), hotCopies.end());
    EXPECT_EQ(field.hotCopies(), hotCopies.size());
    EXPECT_GT(set, 1000);  // the march has cells to blend, and cells to pass over
    EXPECT_GT(clear, 1000);
    // Block distances: a block at D > 0 has no cell that can reach the threshold within D - 1
    // blocks around it, and one at exactly D unless D is the cap.
    const auto nb = tb.blocks;
    auto hasCell = [&](std::int64_t x, std::int64_t y, std::int64_t z) {
        const auto b = static_cast<std::size_t>((x * nb[1] + y) * nb[2] + z);
        return field.blockMask(b) != field.masks();
    };
    int jumps = 0;
    for (std::int64_t x = 0; x < nb[0]; ++x)
        for (std::int64_t y = 0; y < nb[1]; ++y)
            for (std::int64_t z = 0; z < nb[2]; ++z) {
                const auto d = static_cast<int>(
                    field.blockDistance(static_cast<std::size_t>((x * nb[1] + y) * nb[2] + z)));
                ASSERT_EQ(d == 0, hasCell(x, y, z)) << x << " " << y << " " << z;
                int nearest = HitField::kFarBlocks;
                for (std::int64_t a = 0; a < nb[0]; ++a)
                    for (std::int64_t b = 0; b < nb[1]; ++b)
                        for (std::int64_t e = 0; e < nb[2]; ++e)
                            if (hasCell(a, b, e))
                                nearest = std::min<int>(
                                    nearest,
                                    static_cast<int>(std::max(
                                        {std::abs(a - x), std::abs(b - y), std::abs(e - z)})));
                ASSERT_EQ(d, nearest) << x << " " << y << " " << z;
                jumps += d >= 2 ? 1 : 0;
            }
    EXPECT_GT(jumps, 0);
    EXPECT_THROW(HitField(view, std::nanf("")), palp::ValueError);
}
