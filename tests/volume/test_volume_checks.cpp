// The volume library's entry points check every number against palp's bounds (issue 20):
// phantom parameters (voxel, noise, spacings, materials), stored .vdb grids (transform, values),
// the iso-surface (iso value, NaN voxels); OpenVDB's own exceptions reach the caller only inside
// a message naming the grid or file.
#include <gtest/gtest.h>
#include <openvdb/io/File.h>

#include <cmath>
#include <limits>
#include <string>
#include <vector>

#include "palp/base/error.h"
#include "palp/base/validate.h"
#include "palp/volume/load.h"
#include "palp/volume/mesh.h"
#include "palp/volume/phantom.h"
#include "test_support.h"

namespace {

namespace fs = std::filesystem;
using palp::test::expectThrowWith;
namespace pv = palp::volume;
using palp::test::TempDir;

constexpr double kNan = std::numeric_limits<double>::quiet_NaN();
constexpr double kInf = std::numeric_limits<double>::infinity();

// ---------------------------------------------------------------------------------------------
// Phantom parameters

TEST(PhantomChecks, VoxelSizeNanInfNegativeZeroHugeAreRefused) {
    for (const double bad : {kNan, kInf, -kInf, -1.0, 0.0, 1e300, 1e-300}) {
        pv::PhantomSpec spec;
        spec.voxelSize = bad;
        expectThrowWith<palp::ValueError>(
            [&] { pv::makePhantomVolume(spec); },
            {"phantom voxel size: expected a value in [0.001, 100] mm, found " +
             palp::formatValue(bad * 1e3)});
    }
}

TEST(PhantomChecks, NoiseIsBoundedSoNoValueOverflows) {
    pv::PhantomSpec spec;
    spec.voxelSize = 2e-3;
    spec.noiseSigmaHu = 1e300;
    expectThrowWith<palp::ValueError>(
        [&] { pv::makePhantomVolume(spec); },
        {"phantom noise sigma: expected a value in [0, 1e+06], found 1e+300"});
    spec.noiseSigmaHu = kNan;
    expectThrowWith<palp::ValueError>([&] { pv::makePhantomVolume(spec); },
                                      {"phantom noise sigma", "found nan"});
    // The largest noise accepted keeps every value a finite float.
    pv::SliceGeometry g;
    g.pixelSpacing = 4e-3;
    g.sliceSpacing = 4e-3;
    spec.noiseSigmaHu = 1e6;
    const pv::SliceStack st = pv::makePhantomSlices(spec, g);
    for (const auto& s : st.slices)
        for (const float v : s.values) ASSERT_TRUE(std::isfinite(v));
}

TEST(PhantomChecks, SliceGeometryIsChecked) {
    pv::PhantomSpec spec;
    for (const double bad : {kNan, kInf, -1.0, 0.0, 1e300}) {
        pv::SliceGeometry g;
        g.sliceSpacing = bad;
        expectThrowWith<palp::ValueError>([&] { pv::makePhantomSlices(spec, g); },
                                          {"phantom slice spacing: expected a value in"});
        g = {};
        g.pixelSpacing = bad;
        expectThrowWith<palp::ValueError>([&] { pv::makePhantomSlices(spec, g); },
                                          {"phantom pixel spacing: expected a value in"});
        g = {};
        g.sliceGaps = {1e-3, bad};
        expectThrowWith<palp::ValueError>([&] { pv::makePhantomSlices(spec, g); },
                                          {"phantom slice gap: expected a value in"});
    }
    pv::SliceGeometry g;
    g.sliceThickness = kNan;
    expectThrowWith<palp::ValueError>([&] { pv::makePhantomSlices(spec, g); },
                                      {"phantom slice thickness", "found nan"});
    g = {};
    spec.blurSigma = 1.0;  // 2000 pixels: a kernel whose work is not bounded
    expectThrowWith<palp::ValueError>(
        [&] { pv::makePhantomSlices(spec, g); },
        {"phantom blur sigma: expected at most 100 pixel spacings (50mm), found 1000mm"});
    spec.blurSigma = 0;
    spec.margin = 1e300;
    expectThrowWith<palp::ValueError>([&] { pv::makePhantomSlices(spec, g); },
                                      {"phantom margin: expected a value in [0, 10000] mm"});
}

TEST(PhantomChecks, MaterialsAreVolumeValues) {
    pv::PhantomParams p;
    p.materials.rigidHu = 1e300;
    expectThrowWith<palp::ValueError>(
        [&] { pv::Phantom{p}; },
        {"phantom materials: rigid HU: expected a value in [-1e+09, 1e+09], found 1e+300"});
    p.materials.rigidHu = 1000;
    p.materials.fatHu = kNan;
    expectThrowWith<palp::ValueError>([&] { pv::Phantom{p}; },
                                      {"phantom materials: fat HU", "found nan"});
}

// ---------------------------------------------------------------------------------------------
// Stored grids and OpenVDB's exceptions

/// Writes @p grid to @p path as OpenVDB does, without palp's checks.
void writeRawVdb(const openvdb::FloatGrid::Ptr& grid, const fs::path& path) {
    grid->setName("scan");
    openvdb::io::File file(path.string());
    file.write({grid});
    file.close();
}

openvdb::FloatGrid::Ptr cube(float value, double voxel) {
    pv::initialize();
    auto grid = openvdb::FloatGrid::create(-1000.0f);
    grid->setTransform(openvdb::math::Transform::createLinearTransform(voxel));
    grid->tree().fill(openvdb::CoordBBox({0, 0, 0}, {5, 5, 5}), value, true);
    return grid;
}

TEST(VdbChecks, NanValuesOrBackgroundInAStoredGridAreRefusedWithTheFileNamed) {
    TempDir tmp;
    auto grid = cube(100.0f, 1e-3);
    grid->tree().setValue({2, 3, 4}, std::numeric_limits<float>::quiet_NaN());
    writeRawVdb(grid, tmp / "nan.vdb");
    expectThrowWith<palp::FormatError>(
        [&] { pv::load({tmp / "nan.vdb"}); },
        {(tmp / "nan.vdb").string() + ": grid value at (2, 3, 4): expected a value in",
         "found nan"});
    auto bg = openvdb::FloatGrid::create(std::numeric_limits<float>::infinity());
    bg->setTransform(openvdb::math::Transform::createLinearTransform(1e-3));
    bg->tree().setValue({0, 0, 0}, 1.0f);
    writeRawVdb(bg, tmp / "bg.vdb");
    expectThrowWith<palp::FormatError>(
        [&] { pv::loadVdb(tmp / "bg.vdb"); },
        {(tmp / "bg.vdb").string() + ": grid background", "found inf"});
}

TEST(VdbChecks, AStoredTransformMustBeAxisAlignedOrCubicAndInBounds) {
    TempDir tmp;
    writeRawVdb(cube(100.0f, 1.0), tmp / "huge.vdb");
    expectThrowWith<palp::FormatError>(
        [&] { pv::loadVdb(tmp / "huge.vdb"); },
        {(tmp / "huge.vdb").string() + ": grid voxel size: expected a value in [0.001, 100] mm",
         "found 1000"});
    // An axis-aligned scale (native spacing) is read as stored; load() re-grids it to cubic
    // voxels of its smallest edge. A rotated one with non-cubic voxels is refused.
    auto grid = cube(100.0f, 1e-3);
    openvdb::math::Mat4d m = openvdb::math::Mat4d::identity();
    m.setToScale(openvdb::Vec3d(1e-3, 2e-3, 1e-3));
    grid->setTransform(openvdb::math::Transform::createLinearTransform(m));
    writeRawVdb(grid, tmp / "aniso.vdb");
    const pv::Volume stored = pv::loadVdb(tmp / "aniso.vdb");
    EXPECT_FALSE(stored.hasCubicVoxels());
    EXPECT_EQ(stored.voxelSizes(), openvdb::Vec3d(1e-3, 2e-3, 1e-3));
    const pv::Volume cubic = pv::load({tmp / "aniso.vdb"});
    EXPECT_TRUE(cubic.hasCubicVoxels());
    EXPECT_DOUBLE_EQ(cubic.voxelSize(), 1e-3);
    pv::LoadOptions keep;
    keep.resample.nativeSpacing = true;
    EXPECT_EQ(pv::load({tmp / "aniso.vdb"}, keep).voxelSizes(), openvdb::Vec3d(1e-3, 2e-3, 1e-3));
    m.preRotate(openvdb::math::Z_AXIS, 0.3);
    grid->setTransform(openvdb::math::Transform::createLinearTransform(m));
    writeRawVdb(grid, tmp / "rotated.vdb");
    expectThrowWith<palp::FormatError>(
        [&] { pv::loadVdb(tmp / "rotated.vdb"); },
        {(tmp / "rotated.vdb").string() +
             ": grid transform: expected a linear transform with cubic voxels, or an "
             "axis-aligned scale, found voxel (",
         ") mm (rotated)"});
}

TEST(VdbChecks, ResamplingAVolumeChecksTheVoxelSizeBeforeOpenVdb) {
    // A zero voxel size once reached OpenVDB ("Inversion of singular 3x3 matrix").
    const pv::Volume v{cube(100.0f, 1e-3), {}};
    for (const double bad : {0.0, kNan, -1.0, 1e300}) {
        pv::ResampleOptions o;
        o.voxelSize = bad;
        expectThrowWith<palp::ValueError>([&] { pv::resample(v, o); },
                                          {"resample: voxel size: expected a value in"});
    }
    pv::ResampleOptions o;
    o.voxelSize = 2e-3;
    EXPECT_NEAR(pv::resample(v, o).voxelSize(), 2e-3, 1e-15);
}

TEST(MeshChecks, NanVoxelsNeverLeakOpenVdbsBareMessage) {
    auto grid = cube(100.0f, 1e-3);
    grid->tree().setValue({2, 2, 2}, std::numeric_limits<float>::quiet_NaN());
    try {
        pv::isoSurface(*grid, 50.0);
        // OpenVDB may skip the NaN (it is inside a constant region); then the mesh is whole.
        SUCCEED();
    } catch (const palp::ValueError& e) {
        const std::string m = e.what();
        EXPECT_EQ(m.rfind("iso-surface grid: expected finite voxel values", 0), 0u) << m;
    } catch (const std::exception& e) {
        ADD_FAILURE() << "not a palp error: " << e.what();
    }
    expectThrowWith<palp::ValueError>([&] { pv::isoSurface(*cube(1, 1e-3), 1e300); },
                                      {"iso-surface value: expected a value in", "1e+300"});
    pv::initialize();
    auto nanBg = openvdb::FloatGrid::create(std::numeric_limits<float>::quiet_NaN());
    nanBg->tree().setValue({0, 0, 0}, 100.0f);
    expectThrowWith<palp::ValueError>([&] { pv::isoSurface(*nanBg, 50.0); },
                                      {"iso-surface grid background", "found nan"});
}

}  // namespace
