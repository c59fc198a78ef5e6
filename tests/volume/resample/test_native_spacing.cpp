// Native spacing (`--voxel-size native`, ResampleOptions::nativeSpacing): a 0.5 x 0.5 x 1 mm
// series becomes a grid of exactly its own voxels (no doubling to the finest spacing), each voxel
// centred on its pixel's DICOM position and holding its value; slices that are unevenly spaced,
// tilted or off the patient axes are refused with the slice and what was found named.
#include <gtest/gtest.h>

#include <Eigen/Dense>
#include <cmath>
#include <string>
#include <vector>

#include "palp/base/error.h"
#include "palp/volume/dicom.h"
#include "palp/volume/load.h"
#include "palp/volume/resample.h"
#include "test_support.h"

namespace {

namespace pv = palp::volume;
using palp::test::expectThrowWith;
using palp::test::TempDir;

constexpr int kCols = 20, kRows = 16, kSlices = 9;

/// The value of pixel (c, r) of slice k: distinct, positive, exact in uint16 storage.
float pixelValue(int c, int r, int k) { return static_cast<float>(1 + c + 30 * r + 600 * k); }

/// An MR series of kCols x kRows pixels stepping @p colStep and @p rowStep (metres), slice k at
/// origin + along[k] * normal (normal = colStep x rowStep, normalised).
pv::SliceStack series(const Eigen::Vector3d& colStep, const Eigen::Vector3d& rowStep,
                      const std::vector<double>& along, const Eigen::Vector3d& origin) {
    pv::SliceStack s;
    s.info.modality = "MR";
    s.info.sourceFormat = "generated";
    const Eigen::Vector3d n = colStep.cross(rowStep).normalized();
    for (std::size_t k = 0; k < along.size(); ++k) {
        pv::Slice sl;
        sl.cols = kCols;
        sl.rows = kRows;
        sl.colStep = colStep;
        sl.rowStep = rowStep;
        sl.position = origin + along[k] * n;
        sl.source = "slice " + std::to_string(k);
        for (int r = 0; r < kRows; ++r)
            for (int c = 0; c < kCols; ++c)
                sl.values.push_back(pixelValue(c, r, static_cast<int>(k)));
        s.slices.push_back(std::move(sl));
    }
    return s;
}

std::vector<double> evenly(double gap) {
    std::vector<double> a;
    for (int k = 0; k < kSlices; ++k) a.push_back(k * gap);
    return a;
}

const Eigen::Vector3d kOrigin(-5.25e-3, 12.5e-3, -40.75e-3);

pv::ResampleOptions native() {
    pv::ResampleOptions o;
    o.nativeSpacing = true;
    return o;
}

Eigen::Vector3d world(const pv::Volume& v, int x, int y, int z) {
    const openvdb::Vec3d p = v.grid->indexToWorld(openvdb::Coord(x, y, z));
    return {p.x(), p.y(), p.z()};
}

/// Every pixel of @p stack is one active voxel of @p v, at its world position (1e-6 m) with its
/// value.
void expectVoxelPerPixel(const pv::Volume& v, const pv::SliceStack& stack) {
    const std::size_t pixels = static_cast<std::size_t>(kCols) * kRows * stack.slices.size();
    EXPECT_EQ(v.grid->activeVoxelCount(), pixels);
    std::size_t checked = 0;
    for (const pv::Slice& sl : stack.slices) {
        for (int r = 0; r < kRows; ++r) {
            for (int c = 0; c < kCols; ++c) {
                const Eigen::Vector3d p = sl.position + c * sl.colStep + r * sl.rowStep;
                const openvdb::Vec3d ijk = v.grid->worldToIndex(openvdb::Vec3d(p.data()));
                const openvdb::Coord at(static_cast<int>(std::lround(ijk.x())),
                                        static_cast<int>(std::lround(ijk.y())),
                                        static_cast<int>(std::lround(ijk.z())));
                ASSERT_LE((world(v, at.x(), at.y(), at.z()) - p).norm(), 1e-6) << sl.source;
                ASSERT_TRUE(v.grid->tree().isValueOn(at)) << sl.source << " " << c << "," << r;
                const float want = sl.values[static_cast<std::size_t>(r * kCols + c)];
                ASSERT_NEAR(v.grid->tree().getValue(at), want, 1e-3f * want) << sl.source;
                ++checked;
            }
        }
    }
    EXPECT_EQ(checked, pixels);
}

TEST(VolumeNativeSpacing, AnAxialSeriesKeepsItsVoxelsAndTheirPositions) {
    const pv::SliceStack st = series({0.5e-3, 0, 0}, {0, 0.5e-3, 0}, evenly(1e-3), kOrigin);
    const pv::Volume v = pv::resample(st, native());
    EXPECT_FALSE(v.hasCubicVoxels());
    EXPECT_NEAR((v.voxelSizes() - openvdb::Vec3d(0.5e-3, 0.5e-3, 1e-3)).length(), 0, 1e-12);
    const openvdb::CoordBBox box = v.grid->evalActiveVoxelBoundingBox();
    EXPECT_EQ(box.dim(), openvdb::Coord(kCols, kRows, kSlices));
    // Corner voxels sit on the first and last pixel centres.
    const Eigen::Vector3d last(kOrigin + Eigen::Vector3d((kCols - 1) * 0.5e-3, (kRows - 1) * 0.5e-3,
                                                         (kSlices - 1) * 1e-3));
    EXPECT_LE((world(v, box.min().x(), box.min().y(), box.min().z()) - kOrigin).norm(), 1e-6);
    EXPECT_LE((world(v, box.max().x(), box.max().y(), box.max().z()) - last).norm(), 1e-6);
    expectVoxelPerPixel(v, st);
    // The default (finest spacing, 0.5 mm) has about twice the voxels, plus a margin.
    EXPECT_GT(pv::resample(st).grid->activeVoxelCount(), 2 * v.grid->activeVoxelCount());
}

TEST(VolumeNativeSpacing, ASagittalSeriesPutsEachStepOnItsAxis) {
    // Columns along +y (0.5 mm), rows along -z (0.6 mm), the normal along -x, slices 1.2 mm.
    const pv::SliceStack st = series({0, 0.5e-3, 0}, {0, 0, -0.6e-3}, evenly(1.2e-3), kOrigin);
    const pv::Volume v = pv::resample(st, native());
    EXPECT_NEAR((v.voxelSizes() - openvdb::Vec3d(1.2e-3, 0.5e-3, 0.6e-3)).length(), 0, 1e-12);
    EXPECT_EQ(v.grid->evalActiveVoxelBoundingBox().dim(), openvdb::Coord(kSlices, kCols, kRows));
    expectVoxelPerPixel(v, st);
}

TEST(VolumeNativeSpacing, ADicomSeriesConvertsToItsOwnLattice) {
    // Written as DICOM files and read back through load(), which decodes slices lazily.
    TempDir tmp;
    const pv::SliceStack st = series({0.5e-3, 0, 0}, {0, 0.5e-3, 0}, evenly(1e-3), kOrigin);
    pv::DicomWriteOptions wo;
    wo.modality = "MR";
    wo.rescaleIntercept = 0;
    pv::writeDicomSeries(st, tmp / "mr", wo);
    pv::LoadOptions lo;
    lo.resample.nativeSpacing = true;
    const pv::Volume v = pv::load({tmp / "mr"}, lo);
    EXPECT_EQ(v.info.originalDims, (std::array<std::int64_t, 3>{kCols, kRows, kSlices}));
    expectVoxelPerPixel(v, st);

    // Saved and read back: the same transform, bit for bit; load() of the file gives cubic
    // voxels of the smallest edge unless asked to keep the native lattice.
    pv::save(v, tmp / "native.vdb");
    const pv::Volume stored = pv::loadVdb(tmp / "native.vdb");
    EXPECT_EQ(stored.voxelSizes(), v.voxelSizes());
    EXPECT_EQ(world(stored, 3, 4, 5), world(v, 3, 4, 5));
    const pv::Volume cubic = pv::load({tmp / "native.vdb"});
    EXPECT_TRUE(cubic.hasCubicVoxels());
    EXPECT_DOUBLE_EQ(cubic.voxelSize(), 0.5e-3);
    EXPECT_EQ(pv::load({tmp / "native.vdb"}, lo).voxelSizes(), v.voxelSizes());
}

TEST(VolumeNativeSpacing, ACropKeepsTheVoxelsOnThePixelCentres) {
    const pv::SliceStack st = series({0.5e-3, 0, 0}, {0, 0.5e-3, 0}, evenly(1e-3), kOrigin);
    pv::ResampleOptions o = native();
    pv::WorldBox box;
    box.min = kOrigin + Eigen::Vector3d(1.1e-3, 0.7e-3, 2.5e-3);  // between pixel centres
    box.max = kOrigin + Eigen::Vector3d(5e-3, 5e-3, 6e-3);
    o.crop = box;
    const pv::Volume v = pv::resample(st, o);
    const openvdb::CoordBBox b = v.grid->evalActiveVoxelBoundingBox();
    // First centres inside: column 3 (1.5 mm), row 2 (1.0 mm), slice 3 (3 mm).
    EXPECT_LE((world(v, b.min().x(), b.min().y(), b.min().z()) -
               (kOrigin + Eigen::Vector3d(1.5e-3, 1.0e-3, 3e-3)))
                  .norm(),
              1e-9);
    EXPECT_EQ(b.dim(), openvdb::Coord(8, 9, 4));
    EXPECT_FLOAT_EQ(v.grid->tree().getValue(b.min()), pixelValue(3, 2, 3));
}

TEST(VolumeNativeSpacing, UnevenTiltedOrObliqueSlicesAreRefused) {
    std::vector<double> uneven = evenly(1e-3);
    for (int k = 5; k < kSlices; ++k) uneven[static_cast<std::size_t>(k)] += 0.5e-3;
    expectThrowWith<palp::ValueError>(
        [&] {
            pv::resample(series({0.5e-3, 0, 0}, {0, 0.5e-3, 0}, uneven, kOrigin), native());
        },
        {"resample: native spacing (slice ",
         "expected evenly spaced slices (each within 1 % of "
         "the mean gap of 1.0625 mm), or a voxel size",
         "found gaps from 1 to 1.5 mm"});
    // Still a series the default resampling takes.
    EXPECT_NO_THROW(pv::resample(series({0.5e-3, 0, 0}, {0, 0.5e-3, 0}, uneven, kOrigin)));

    pv::SliceStack tilted = series({0.5e-3, 0, 0}, {0, 0.5e-3, 0}, evenly(1e-3), kOrigin);
    for (std::size_t k = 0; k < tilted.slices.size(); ++k)
        tilted.slices[k].position.y() += 0.2e-3 * static_cast<double>(k);
    expectThrowWith<palp::ValueError>([&] { pv::resample(tilted, native()); },
                                      {"resample: native spacing (slice 1)",
                                       "expected slices stacked along their normal (no gantry "
                                       "tilt)",
                                       "found a shift of 0.2 mm in plane from slice 0"});

    const double t = 0.2;  // radians about z
    expectThrowWith<palp::ValueError>(
        [&] {
            pv::resample(series(0.5e-3 * Eigen::Vector3d(std::cos(t), std::sin(t), 0),
                                0.5e-3 * Eigen::Vector3d(-std::sin(t), std::cos(t), 0),
                                evenly(1e-3), kOrigin),
                         native());
        },
        {"resample: native spacing (slice 0)",
         "expected rows, columns and slice normal along "
         "the patient axes"});

    pv::ResampleOptions both = native();
    both.voxelSize = 1e-3;
    expectThrowWith<palp::ValueError>(
        [&] { pv::checkResampleOptions(both); },
        {"resample: voxel size: expected none with native spacing, found 1 mm"});
}

}  // namespace
