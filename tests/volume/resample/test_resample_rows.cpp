// The resampler's row kernel against its voxel-by-voxel reference and against a direct
// evaluation of the documented interpolation, on tilted series in several orientations; its
// AVX2 rows against its scalar rows, bit for bit; and its
// memory on a larger generated series (at most the output grid plus half of it).
#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <optional>
#include <string>
#include <tuple>

#include "memory_use.h"
#include "palp/volume/resample.h"
#include "resample/resample_detail.h"
#include "tilted_series.h"

namespace {

using palp::volume::Slice;
using palp::volume::SliceStack;
using palp::volume::Volume;

/// The stack turned rigidly by @p R about the world origin (values unchanged).
SliceStack rotated(SliceStack s, const Eigen::Matrix3d& R) {
    for (Slice& sl : s.slices) {
        sl.position = R * sl.position;
        sl.colStep = R * sl.colStep;
        sl.rowStep = R * sl.rowStep;
    }
    return s;
}

/// The stack with world axes permuted exactly: a vector v becomes (v[k], v[k + 1], v[k + 2])
/// (indices mod 3), so with @p k = 1 the x of every vector moves to z.
SliceStack permuted(SliceStack s, int k) {
    const auto perm = [k](const Eigen::Vector3d& v) {
        return Eigen::Vector3d(v[k % 3], v[(k + 1) % 3], v[(k + 2) % 3]);
    };
    for (Slice& sl : s.slices) {
        sl.position = perm(sl.position);
        sl.colStep = perm(sl.colStep);
        sl.rowStep = perm(sl.rowStep);
    }
    return s;
}

/// The documented interpolation evaluated directly at world point @p p: the two slices that
/// bracket p along the normal, each sampled bilinearly (edge pixels extended) at p's foot on its
/// plane, blended linearly by distance along the normal. Only for p strictly inside the slices'
/// range along the normal and inside both slices' pixel centres.
bool direct(const SliceStack& st, const Eigen::Vector3d& p, double& out) {
    const Slice& f = st.slices.front();
    const Eigen::Vector3d n = f.colStep.cross(f.rowStep).normalized();
    const double sp = p.dot(n);
    const Slice* below = nullptr;
    const Slice* above = nullptr;
    for (const Slice& s : st.slices) {
        const double a = s.position.dot(n);
        if (a <= sp && (!below || a > below->position.dot(n))) below = &s;
        if (a > sp && (!above || a < above->position.dot(n))) above = &s;
    }
    if (!below || !above) return false;
    const auto bilinear = [&](const Slice& s, double& v) {
        // Solve p - position = c u + r v + h n in the least-squares sense (u, v not unit).
        Eigen::Matrix<double, 3, 2> A;
        A.col(0) = s.colStep;
        A.col(1) = s.rowStep;
        const Eigen::Vector2d cr =
            (A.transpose() * A).ldlt().solve(A.transpose() * (p - s.position));
        if (cr.x() < 0 || cr.y() < 0 || cr.x() > s.cols - 1 || cr.y() > s.rows - 1) return false;
        const int c0 = std::min(static_cast<int>(cr.x()), s.cols - 2);
        const int r0 = std::min(static_cast<int>(cr.y()), s.rows - 2);
        const double fc = cr.x() - c0, fr = cr.y() - r0;
        const auto at = [&](int c, int r) {
            return static_cast<double>(s.values[static_cast<std::size_t>(r * s.cols + c)]);
        };
        v = (at(c0, r0) * (1 - fc) + at(c0 + 1, r0) * fc) * (1 - fr) +
            (at(c0, r0 + 1) * (1 - fc) + at(c0 + 1, r0 + 1) * fc) * fr;
        return true;
    };
    double va = 0, vb = 0;
    if (!bilinear(*below, va) || !bilinear(*above, vb)) return false;
    const double a = below->position.dot(n), b = above->position.dot(n);
    const double t = (sp - a) / (b - a);
    out = va * (1 - t) + vb * t;
    return true;
}

struct Comparison {
    std::int64_t active = 0, directChecked = 0, topologyDiffers = 0;
    double maxReferenceDiff = 0, maxDirectDiff = 0;
};

/// Compares every voxel of @p fast with @p ref (values and activity; a voxel may differ in
/// activity only when its value is within 1e-3 of the threshold) and its active voxels with the
/// direct evaluation.
Comparison compare(const SliceStack& st, const Volume& fast, const Volume& ref, float threshold) {
    Comparison out;
    auto fa = fast.grid->getConstAccessor();
    auto ra = ref.grid->getConstAccessor();
    openvdb::CoordBBox box = fast.grid->evalActiveVoxelBoundingBox();
    box.expand(ref.grid->evalActiveVoxelBoundingBox());
    for (auto it = box.begin(); it; ++it) {
        const openvdb::Coord ijk = *it;
        const float vf = fa.getValue(ijk), vr = ra.getValue(ijk);
        const bool af = fa.isValueOn(ijk), ar = ra.isValueOn(ijk);
        if (af != ar) {
            ++out.topologyDiffers;
            if (std::abs((af ? vf : vr) - threshold) > 1e-3f) ++out.topologyDiffers;  // counts 2
            continue;
        }
        out.maxReferenceDiff = std::max(out.maxReferenceDiff, std::abs(double(vf) - double(vr)));
        if (!af) continue;
        ++out.active;
        const openvdb::Vec3d w = fast.grid->indexToWorld(ijk);
        double d = 0;
        if (direct(st, Eigen::Vector3d(w.x(), w.y(), w.z()), d)) {
            ++out.directChecked;
            out.maxDirectDiff = std::max(out.maxDirectDiff, std::abs(double(vf) - d));
        }
    }
    return out;
}

TEST(ResampleRows, RowKernelGivesTheReferenceVoxelsOnTiltedSeriesInEveryOrientation) {
    const SliceStack axial = palp::test::tiltedSeries(48, 40, 14, 0.7e-3, 1.3e-3, 17.0);
    const std::vector<std::pair<std::string, Eigen::Matrix3d>> orientations = {
        {"axial", Eigen::Matrix3d::Identity()},
        // Slices normal to x (sagittal) with the normal pointing to -x: rows run along -x.
        {"sagittal", Eigen::AngleAxisd(M_PI / 2, Eigen::Vector3d::UnitY()).toRotationMatrix()},
        // Oblique in all three axes.
        {"oblique", (Eigen::AngleAxisd(0.5, Eigen::Vector3d::UnitX()) *
                     Eigen::AngleAxisd(-0.8, Eigen::Vector3d::UnitY()) *
                     Eigen::AngleAxisd(0.3, Eigen::Vector3d::UnitZ()))
                        .toRotationMatrix()}};
    for (const auto& [name, R] : orientations) {
        SCOPED_TRACE(name);
        const SliceStack st = rotated(axial, R);
        palp::volume::ResampleOptions opt;
        opt.voxelSize = 0.45e-3;
        const Volume fast = palp::volume::resample(st, opt);
        const Volume ref = palp::volume::detail::resampleVoxelByVoxel(st, opt);
        const Comparison c = compare(st, fast, ref, -900.0f);
        EXPECT_GT(c.active, 50000) << "the series must fill a good part of the grid";
        EXPECT_EQ(c.topologyDiffers % 2, 0) << "activity differs away from the threshold";
        EXPECT_LE(c.topologyDiffers, 4);
        EXPECT_LE(c.maxReferenceDiff, 1e-3) << "HU";
        // The direct evaluation covers the interior (away from the slices' edges).
        EXPECT_GT(c.directChecked, c.active / 2);
        EXPECT_LE(c.maxDirectDiff, 2e-3) << "HU";
        EXPECT_EQ(fast.grid->background(), ref.grid->background());
        EXPECT_TRUE(fast.grid->transform() == ref.grid->transform());
    }
}

/// Voxels (value or activity) in which @p a and @p b differ at all, over both active boxes.
std::int64_t voxelsDiffering(const Volume& a, const Volume& b) {
    auto aa = a.grid->getConstAccessor();
    auto ba = b.grid->getConstAccessor();
    openvdb::CoordBBox box = a.grid->evalActiveVoxelBoundingBox();
    box.expand(b.grid->evalActiveVoxelBoundingBox());
    std::int64_t differ = 0;
    for (auto it = box.begin(); it; ++it) {
        const float va = aa.getValue(*it), vb = ba.getValue(*it);
        if (aa.isValueOn(*it) != ba.isValueOn(*it) || std::memcmp(&va, &vb, sizeof va) != 0)
            ++differ;
    }
    return differ;
}

TEST(ResampleRows, VectorRowsGiveTheScalarRowsBitForBit) {
    // Gantry tilt about x: the slices share their column coordinate (one column per voxel for
    // both); then every other slice shifted by a third of a pixel along its rows (a column per
    // slice). Where the CPU has no AVX2 both grids come from the scalar rows. At 0.45 and 0.7 mm
    // four voxels of a row span at most eight pixels, which the vector rows load and permute; at
    // 1.6 mm they span more and the vector rows gather them.
    const SliceStack tilted = palp::test::tiltedSeries(48, 40, 14, 0.7e-3, 1.3e-3, 17.0);
    SliceStack shifted = tilted;
    for (std::size_t k = 1; k < shifted.slices.size(); k += 2)
        shifted.slices[k].position += shifted.slices[k].colStep / 3;
    for (const auto& [name, st] : {std::pair{"tilted", tilted}, std::pair{"shifted", shifted}}) {
        for (const double voxel : {0.45e-3, 0.7e-3, 1.6e-3}) {
            SCOPED_TRACE(std::string(name) + ", voxel " + std::to_string(voxel * 1e3) + " mm");
            palp::volume::ResampleOptions opt;
            opt.voxelSize = voxel;
            const Volume fast = palp::volume::resample(st, opt);
            const Volume scalar = palp::volume::detail::resampleScalarRows(st, opt);
            EXPECT_GT(fast.grid->activeVoxelCount(), voxel < 1e-3 ? 10000u : 1000u);
            EXPECT_EQ(fast.grid->activeVoxelCount(), scalar.grid->activeVoxelCount());
            EXPECT_EQ(voxelsDiffering(fast, scalar), 0);
        }
    }
}

TEST(ResampleRows, RowsOfBlocksGiveTheBlockByBlockRowsBitForBit) {
    // An axial series with and without gantry tilt: every slice at the same column coordinates,
    // so rows of blocks interpolate each pixel row's columns once (fillBlockRow); block by block
    // is the reference. The rows run along x, y or z with the slices' columns. A partial last
    // block along every axis (the dimensions are not multiples of 8), crops, and voxels of 0.45
    // to 1.6 mm.
    const SliceStack tilted = palp::test::tiltedSeries(48, 40, 14, 0.7e-3, 1.3e-3, 17.0);
    const SliceStack straight = palp::test::tiltedSeries(37, 29, 9, 0.8e-3, 2.1e-3, 0.0);
    // The tilted series with its axes permuted exactly (no rounding, unlike a rotation): the
    // slices' columns run along y, then along z, so the rows of blocks run along y, then z.
    const SliceStack alongY = permuted(tilted, 2);
    const SliceStack alongZ = permuted(tilted, 1);
    // A crop inside the slices along every axis: the lattice's last block along x ends inside
    // the slices' columns.
    palp::volume::WorldBox inside;
    inside.min = Eigen::Vector3d(5.1e-3, 4.3e-3, 3.2e-3);
    inside.max = Eigen::Vector3d(26.3e-3, 20.1e-3, 14.2e-3);
    palp::volume::WorldBox insideZ;  // the same box with its axes permuted as alongZ's
    insideZ.min = Eigen::Vector3d(inside.min.y(), inside.min.z(), inside.min.x());
    insideZ.max = Eigen::Vector3d(inside.max.y(), inside.max.z(), inside.max.x());
    const std::optional<palp::volume::WorldBox> whole;
    for (const auto& [name, st, crop] :
         {std::tuple{"tilted", tilted, whole}, std::tuple{"straight", straight, whole},
          std::tuple{"columns along y", alongY, whole},
          std::tuple{"columns along z", alongZ, whole},
          std::tuple{"columns along z, cropped", alongZ, std::optional{insideZ}},
          std::tuple{"tilted, cropped", tilted, std::optional{inside}}}) {
        for (const double voxel : {0.45e-3, 0.7e-3, 1.6e-3}) {
            SCOPED_TRACE(std::string(name) + ", voxel " + std::to_string(voxel * 1e3) + " mm");
            palp::volume::ResampleOptions opt;
            opt.voxelSize = voxel;
            opt.crop = crop;
            const Volume rows = palp::volume::resample(st, opt);
            const Volume perBlock = palp::volume::detail::resamplePerBlockRows(st, opt);
            const Volume scalar = palp::volume::detail::resampleScalarRows(st, opt);
            EXPECT_GT(rows.grid->activeVoxelCount(), voxel < 1e-3 ? 5000u : 500u);
            EXPECT_EQ(rows.grid->activeVoxelCount(), perBlock.grid->activeVoxelCount());
            EXPECT_EQ(rows.grid->tree().leafCount(), perBlock.grid->tree().leafCount());
            EXPECT_EQ(voxelsDiffering(rows, perBlock), 0);
            EXPECT_EQ(voxelsDiffering(rows, scalar), 0);
        }
    }
}

TEST(ResampleRows, PeakMemoryOfALargerSeriesStaysWithinHalfTheGridAboveIt) {
    // 320 x 320 x 200 tilted slices at 0.5 mm (82 MB of input): a ~23 M voxel lattice, ~7 M of
    // them active. Resampling may hold the output grid and at most half of it again (the
    // blocks in flight, the tree's internal nodes): no dense copy of the lattice.
#if defined(__SANITIZE_ADDRESS__) || defined(__SANITIZE_THREAD__)
    GTEST_SKIP() << "the sanitizer's shadow memory and quarantine change the resident set";
#endif
    const SliceStack st = palp::test::tiltedSeries(320, 320, 200, 0.5e-3, 0.5e-3, 12.0);
    std::ofstream("/proc/self/clear_refs") << "5";  // resets VmHWM to the current RSS
    const auto [before, peak0] = palp::test::rssAndPeak();
    if (std::abs(peak0 - before) > 4e6) GTEST_SKIP() << "this kernel cannot reset VmHWM";
    const Volume v = palp::volume::resample(st);
    const auto [after, peak] = palp::test::rssAndPeak();
    const double grid = static_cast<double>(v.grid->memUsage());
    EXPECT_GT(v.grid->activeVoxelCount(), 5'000'000u);
    EXPECT_GT(after - before, 0.8 * grid) << "the grid lives in this process";
    std::printf("resample: peak %.1f MB above the input, grid %.1f MB (%.2fx)\n",
                (peak - before) / 1e6, grid / 1e6, (peak - before) / grid);
    EXPECT_LE(peak - before, 1.5 * grid)
        << "peak " << (peak - before) / 1e6 << " MB over a " << grid / 1e6 << " MB grid";
}

}  // namespace
