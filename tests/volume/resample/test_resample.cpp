#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <cmath>

#include "palp/base/error.h"
#include "palp/kernels/trilinear.h"
#include "palp/volume/resample.h"

namespace {

using palp::volume::Slice;
using palp::volume::SliceStack;

// A linear world field; bilinear-in-plane plus linear-along-normal interpolation reproduces it
// exactly, so any geometric error of the resampler shows up as a value error.
double field(const Eigen::Vector3d& p) {
    return 1000.0 * (p.x() * 40 - p.y() * 25 + p.z() * 60) + 200.0;
}

// A tilted stack with uneven slice gaps: in-plane axes rotated about x by the tilt, slices
// stacked along world z (as a CT gantry tilt does), gaps alternating.
SliceStack tiltedStack(double tiltDeg, const std::vector<double>& gapsMm, int cols = 24,
                       int rows = 20) {
    SliceStack st;
    st.info.modality = "CT";
    const double t = tiltDeg * M_PI / 180.0;
    const Eigen::Vector3d u = Eigen::Vector3d(1, 0, 0) * 0.7e-3;
    const Eigen::Vector3d v = Eigen::Vector3d(0, std::cos(t), -std::sin(t)) * 0.7e-3;
    Eigen::Vector3d pos(-5e-3, -6e-3, 10e-3);
    for (std::size_t k = 0; k <= gapsMm.size(); ++k) {
        Slice s;
        s.position = pos;
        s.colStep = u;
        s.rowStep = v;
        s.cols = cols;
        s.rows = rows;
        s.source = "slice" + std::to_string(k);
        for (int r = 0; r < rows; ++r)
            for (int c = 0; c < cols; ++c)
                s.values.push_back(static_cast<float>(field(pos + c * u + r * v)));
        st.slices.push_back(std::move(s));
        if (k < gapsMm.size()) pos += Eigen::Vector3d(0, 0, gapsMm[k] * 1e-3);
    }
    return st;
}

struct Errors {
    double maxAbs = 0;
    int inside = 0;
};

/// True when @p p lies within the data: between the first and last slice along the normal and
/// inside the pixel centres of the two slices that bracket it. Outside, the resampler extends
/// edge values by up to a voxel, which a linear field does not follow.
bool insideData(const SliceStack& st, const Eigen::Vector3d& p) {
    const Slice& f = st.slices.front();
    const Eigen::Vector3d n = f.colStep.cross(f.rowStep).normalized();
    const double sp = p.dot(n);
    double lo = 1e300, hi = -1e300;
    for (const Slice& s : st.slices) {
        lo = std::min(lo, s.position.dot(n));
        hi = std::max(hi, s.position.dot(n));
    }
    if (sp < lo || sp > hi) return false;
    for (const Slice& s : st.slices) {
        const Eigen::Vector3d q = p - s.position;
        const double c =
            q.dot(s.colStep) / s.colStep.squaredNorm();  // orthogonal steps in these tests
        const double r = q.dot(s.rowStep) / s.rowStep.squaredNorm();
        if (c < 0 || c > s.cols - 1 || r < 0 || r > s.rows - 1) return false;
    }
    return true;
}

Errors compareWithField(const palp::volume::Volume& vol, const SliceStack& st) {
    Errors e;
    const auto& xf = vol.grid->transform();
    for (auto it = vol.grid->cbeginValueOn(); it; ++it) {
        const openvdb::Vec3d w = xf.indexToWorld(it.getCoord());
        if (!insideData(st, {w.x(), w.y(), w.z()})) continue;
        e.maxAbs = std::max(e.maxAbs, std::abs(*it - field({w.x(), w.y(), w.z()})));
        ++e.inside;
    }
    return e;
}

TEST(Resample, TiltedUnevenStackReproducesLinearFieldExactly) {
    const SliceStack st = tiltedStack(18.5, {1.0, 3.0, 1.0, 7.0, 2.0});
    palp::volume::ResampleOptions opt;
    opt.voxelSize = 0.5e-3;
    opt.backgroundThreshold = -1e9f;
    const auto vol = palp::volume::resample(st, opt);
    const Errors e = compareWithField(vol, st);
    EXPECT_GT(e.inside, 1000);
    EXPECT_LT(e.maxAbs, 1e-3);  // float rounding of values around a few hundred
    EXPECT_NEAR(vol.info.gantryTiltDeg, 18.5, 1e-6);
    EXPECT_NEAR(vol.info.minSliceGap, 1e-3 * std::cos(18.5 * M_PI / 180), 1e-9);
    EXPECT_NEAR(vol.info.maxSliceGap, 7e-3 * std::cos(18.5 * M_PI / 180), 1e-9);
    EXPECT_DOUBLE_EQ(vol.voxelSize(), 0.5e-3);
}

TEST(Resample, IgnoringTiltOrFlippingAnAxisIsDetected) {
    // The negative control: the same values with wrong geometry must not pass the check above.
    SliceStack st = tiltedStack(18.5, {1.0, 3.0, 1.0, 7.0, 2.0});
    SliceStack untilted = st;
    for (Slice& s : untilted.slices) s.rowStep = Eigen::Vector3d(0, 0.7e-3, 0);
    palp::volume::ResampleOptions opt;
    opt.voxelSize = 0.5e-3;
    opt.backgroundThreshold = -1e9f;
    EXPECT_GT(compareWithField(palp::volume::resample(untilted, opt), st).maxAbs, 10.0);
    SliceStack flipped = st;
    for (Slice& s : flipped.slices) s.colStep = -s.colStep;
    EXPECT_GT(compareWithField(palp::volume::resample(flipped, opt), st).maxAbs, 10.0);
}

TEST(Resample, TrilinearSamplingIsExactUpToTheDataEdge) {
    // Points on the first and last slices and on the outermost rows and columns: a trilinear
    // sample of the grid reproduces the slice there (the grid extends edge values by a voxel).
    const SliceStack st = tiltedStack(18.5, {1.0, 3.0, 1.0, 7.0, 2.0});
    palp::volume::ResampleOptions opt;
    opt.voxelSize = 0.5e-3;
    opt.backgroundThreshold = -1e9f;
    const auto vol = palp::volume::resample(st, opt);
    const auto acc = vol.grid->getConstAccessor();
    double worst = 0;
    int checked = 0;
    for (const Slice& s : st.slices)
        for (int r = 0; r < s.rows; ++r)
            for (int c = 0; c < s.cols; ++c) {
                const Eigen::Vector3d p = s.position + c * s.colStep + r * s.rowStep;
                const double v = palp::kernels::sampleWorld(acc, vol.grid->transform(),
                                                            openvdb::Vec3d(p.data()));
                worst = std::max(worst, std::abs(v - field(p)));
                ++checked;
            }
    EXPECT_EQ(checked, 6 * 24 * 20);
    // Inside, interpolation of a linear field is exact; at the very edge the extended values
    // deviate from the field by at most the field's change over one voxel (~50 units here).
    EXPECT_LT(worst, 60.0);
}

TEST(Resample, SliceOrderDoesNotMatter) {
    SliceStack st = tiltedStack(0, {2.0, 2.0, 2.0});
    std::swap(st.slices[0], st.slices[3]);
    std::swap(st.slices[1], st.slices[2]);
    palp::volume::ResampleOptions opt;
    opt.backgroundThreshold = -1e9f;
    const Errors e = compareWithField(palp::volume::resample(st, opt), st);
    EXPECT_LT(e.maxAbs, 1e-3);
}

TEST(Resample, AxisAlignedSourceAtItsOwnSpacingIsLossless) {
    SliceStack st = tiltedStack(0, {0.7, 0.7, 0.7});
    const auto vol = palp::volume::resample(st, {});  // default voxel = finest spacing = 0.7 mm
    EXPECT_NEAR(vol.voxelSize(), 0.7e-3, 1e-12);
    // Every source pixel is a voxel centre and keeps its value.
    const auto acc = vol.grid->getConstAccessor();
    for (const Slice& s : st.slices)
        for (int r = 0; r < s.rows; ++r)
            for (int c = 0; c < s.cols; ++c) {
                const Eigen::Vector3d p = s.position + c * s.colStep + r * s.rowStep;
                const openvdb::Vec3d ip =
                    vol.grid->transform().worldToIndex(openvdb::Vec3d(p.data()));
                const openvdb::Coord ijk = openvdb::Coord::round(ip);
                EXPECT_NEAR((ip - ijk.asVec3d()).length(), 0.0, 1e-6);
                EXPECT_EQ(acc.getValue(ijk), s.values[static_cast<std::size_t>(r * s.cols + c)]);
            }
}

TEST(Resample, BackgroundThresholdMakesGridSparse) {
    SliceStack st = tiltedStack(0, {1.0, 1.0});
    for (Slice& s : st.slices)
        for (std::size_t i = 0; i < s.values.size(); ++i) s.values[i] = (i % 2) ? 100.0f : -1000.0f;
    const auto vol = palp::volume::resample(st, {});
    EXPECT_EQ(vol.grid->background(), -1000.0f);
    for (auto it = vol.grid->cbeginValueOn(); it; ++it) EXPECT_GE(*it, -900.0f);
    EXPECT_GT(vol.grid->activeVoxelCount(), 0u);
}

TEST(Resample, SkippingBackgroundBlocksLosesNoActiveVoxel) {
    // Mostly air with small bright islands: the block skip (tile maxima) must keep exactly the
    // voxels that a resample without any skipping (threshold -1e9) finds above the threshold.
    SliceStack st = tiltedStack(18.5, {1.0, 3.0, 1.0, 7.0, 2.0}, 64, 48);
    std::uint32_t h = 12345;
    for (Slice& s : st.slices)
        for (float& v : s.values) {
            h = h * 1664525u + 1013904223u;
            v = (h >> 24) < 6 ? 300.0f + static_cast<float>(h >> 28) : -1000.0f;
        }
    palp::volume::ResampleOptions all;
    all.voxelSize = 0.5e-3;
    all.backgroundThreshold = -1e9f;
    palp::volume::ResampleOptions sparse;
    sparse.voxelSize = 0.5e-3;
    sparse.backgroundThreshold = -900.0f;
    const auto full = palp::volume::resample(st, all);
    const auto skip = palp::volume::resample(st, sparse);
    std::size_t expected = 0;
    const auto acc = skip.grid->getConstAccessor();
    for (auto it = full.grid->cbeginValueOn(); it; ++it) {
        if (*it < -900.0f) continue;
        ++expected;
        ASSERT_TRUE(acc.isValueOn(it.getCoord())) << it.getCoord();
        ASSERT_EQ(acc.getValue(it.getCoord()), *it);
    }
    EXPECT_GT(expected, 100u);
    EXPECT_EQ(skip.grid->activeVoxelCount(), expected);
}

TEST(Resample, BadStacksAreRefusedWithReasons) {
    palp::volume::SliceStack empty;
    EXPECT_THROW(palp::volume::resample(empty, {}), palp::ValueError);
    SliceStack dup = tiltedStack(0, {1.0});
    dup.slices[1].position = dup.slices[0].position;
    try {
        palp::volume::resample(dup, {});
        FAIL() << "repeated positions accepted";
    } catch (const palp::ValueError& e) {
        EXPECT_NE(std::string(e.what()).find("distinct slice positions"), std::string::npos)
            << e.what();
    }
    SliceStack rotated = tiltedStack(0, {1.0});
    rotated.slices[1].colStep = Eigen::Vector3d(0, 0.7e-3, 0);
    EXPECT_THROW(palp::volume::resample(rotated, {}), palp::ValueError);
    SliceStack huge = tiltedStack(0, {1.0});
    palp::volume::ResampleOptions opt;
    opt.voxelSize = 1e-9;
    EXPECT_THROW(palp::volume::resample(huge, opt), palp::ValueError);
    opt.voxelSize = -1.0;
    EXPECT_THROW(palp::volume::resample(huge, opt), palp::ValueError);
}

TEST(Resample, CropKeepsOnlyTheBox) {
    const SliceStack st = tiltedStack(0, {1.0, 1.0, 1.0, 1.0});
    palp::volume::ResampleOptions opt;
    opt.backgroundThreshold = -1e9f;
    opt.crop = palp::volume::WorldBox{Eigen::Vector3d(-3e-3, -4e-3, 11e-3),
                                      Eigen::Vector3d(2e-3, 1e-3, 12.5e-3)};
    const auto vol = palp::volume::resample(st, opt);
    const auto b = vol.worldBounds();
    EXPECT_GE(b.min().x(), -3e-3 - 1e-9);
    EXPECT_LE(b.max().x(), 2e-3 + 1e-9);
    EXPECT_LE(b.max().z(), 12.5e-3 + 1e-9);
    EXPECT_LT(compareWithField(vol, st).maxAbs, 1e-3);
}

}  // namespace
