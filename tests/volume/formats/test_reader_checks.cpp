// The readers refuse what they cannot honour (issue 20): a spacing, direction or origin a header
// gives is used or refused, never replaced by 1 mm; NaN or infinite voxels are refused at load
// with the file named; OpenVDB's own exceptions never reach the caller without the file or
// field. Each refusal names the file and the field, what was expected and what was found.
#include <gtest/gtest.h>
#include <nifti1.h>

#include <cmath>
#include <cstring>
#include <fstream>
#include <limits>
#include <string>
#include <vector>

#include "formats/formats.h"
#include "palp/base/error.h"
#include "palp/volume/load.h"
#include "palp/volume/resample.h"
#include "test_support.h"

namespace {

namespace fs = std::filesystem;
using palp::test::expectThrowWith;
using palp::test::floatsLE;
using palp::test::TempDir;
using palp::test::writeFile;
using palp::volume::SliceStack;

/// 2x2x2 floats 0..7, or @p values.
std::string eightFloats(std::vector<float> values = {0, 1, 2, 3, 4, 5, 6, 7}) {
    return floatsLE(values);
}

fs::path nrrd(const TempDir& tmp, const std::string& name, const std::string& geometry,
              const std::string& data = eightFloats()) {
    const fs::path file = tmp / name;
    writeFile(file, "NRRD0004\ntype: float\ndimension: 3\nsizes: 2 2 2\n" + geometry +
                        "endian: little\nencoding: raw\n\n" + data);
    return file;
}

// ---------------------------------------------------------------------------------------------
// NRRD

TEST(NrrdChecks, ZeroOrNanSpacingsAreRefusedNotReplacedByOneMillimetre) {
    TempDir tmp;
    for (const std::string bad : {"0 0 0", "nan nan nan", "1 inf 1", "1 1 -nan"}) {
        const fs::path file = nrrd(tmp, "s.nrrd", "spacings: " + bad + "\n");
        expectThrowWith<palp::FormatError>(
            [&] { palp::volume::readNrrd(file, {}); },
            {file.string() + ": spacings (axis ", "expected a finite non-zero spacing"});
    }
    const fs::path file = nrrd(tmp, "z.nrrd", "spacings: 1 0 1\n");
    expectThrowWith<palp::FormatError>([&] { palp::volume::readNrrd(file, {}); },
                                       {file.string() + ": spacings (axis 1)", "found 0"});
}

TEST(NrrdChecks, AbsurdSpacingsAreRefusedWithTheBounds) {
    TempDir tmp;
    const fs::path huge = nrrd(tmp, "h.nrrd", "spacings: 1 1e300 1\n");
    expectThrowWith<palp::FormatError>(
        [&] { palp::volume::readNrrd(huge, {}); },
        {huge.string() + ": spacings (axis 1 step): expected a value in [0.001, 100] mm",
         "found 1e+300"});
    const fs::path tiny = nrrd(tmp, "t.nrrd", "spacings: 1e-9 1 1\n");
    expectThrowWith<palp::FormatError>([&] { palp::volume::readNrrd(tiny, {}); },
                                       {tiny.string() + ": spacings (axis 0 step)"});
}

TEST(NrrdChecks, AbsentSpacingsStillMeanOneMillimetre) {
    // Documented accept: a file that says nothing about spacing gets 1 mm per sample.
    TempDir tmp;
    const fs::path file = nrrd(tmp, "none.nrrd", "");
    const SliceStack st = palp::volume::readNrrd(file, {});
    ASSERT_EQ(st.slices.size(), 2u);
    EXPECT_DOUBLE_EQ(st.slices[0].colStep.x(), 1e-3);
    EXPECT_DOUBLE_EQ(st.slices[1].position.z(), 1e-3);
}

TEST(NrrdChecks, DegenerateAxisRangeIsRefused) {
    TempDir tmp;
    const fs::path file = nrrd(tmp, "r.nrrd", "axis mins: 0 0 0\naxis maxs: 1 0 1\n");
    expectThrowWith<palp::FormatError>(
        [&] { palp::volume::readNrrd(file, {}); },
        {file.string() + ": axis mins, axis maxs (axis 1)", "found 0 to 0"});
}

TEST(NrrdChecks, ZeroOrParallelSpaceDirectionsAreRefused) {
    TempDir tmp;
    const fs::path zero = nrrd(tmp, "zero.nrrd",
                               "space: left-posterior-superior\n"
                               "space directions: (1,0,0) (0,0,0) (0,0,1)\n");
    expectThrowWith<palp::FormatError>(
        [&] { palp::volume::readNrrd(zero, {}); },
        {zero.string() + ": space directions (axis 1 step): expected a value in", "found 0"});
    const fs::path parallel = nrrd(tmp, "par.nrrd",
                                   "space: left-posterior-superior\n"
                                   "space directions: (1,0,0) (2,0,0) (0,0,1)\n");
    expectThrowWith<palp::FormatError>(
        [&] { palp::volume::readNrrd(parallel, {}); },
        {parallel.string() + ": space directions: expected three independent axis directions",
         "(1 0 0), (2 0 0), (0 0 1) mm"});
    const fs::path far = nrrd(tmp, "far.nrrd",
                              "space: left-posterior-superior\n"
                              "space directions: (1,0,0) (0,1,0) (0,0,1)\n"
                              "space origin: (0,1e300,0)\n");
    expectThrowWith<palp::FormatError>(
        [&] { palp::volume::readNrrd(far, {}); },
        {far.string() + ": space origin (coordinate 1): expected a value in [-10000, 10000] mm",
         "found 1e+300"});
}

// ---------------------------------------------------------------------------------------------
// MetaImage

fs::path mha(const TempDir& tmp, const std::string& name, const std::string& geometry,
             const std::string& data = eightFloats()) {
    const fs::path file = tmp / name;
    writeFile(file, "ObjectType = Image\nNDims = 3\nDimSize = 2 2 2\n" + geometry +
                        "ElementType = MET_FLOAT\nElementDataFile = LOCAL\n" + data);
    return file;
}

TEST(MetaImageChecks, ElementSpacingTransformMatrixAndOffsetAreChecked) {
    TempDir tmp;
    const fs::path zero = mha(tmp, "s.mha", "ElementSpacing = 1 0 1\n");
    expectThrowWith<palp::FormatError>(
        [&] { palp::volume::readMetaImage(zero, {}); },
        {zero.string() + ": ElementSpacing (axis 1): expected a finite non-zero spacing",
         "found 0"});
    // The header parser already refuses non-finite numbers, naming the line.
    for (const std::string bad : {"1 nan 1", "1 1 inf"}) {
        const fs::path file = mha(tmp, "s.mha", "ElementSpacing = " + bad + "\n");
        expectThrowWith<palp::FormatError>(
            [&] { palp::volume::readMetaImage(file, {}); },
            {file.string() + ": line 4: expected 'ElementSpacing' with 3 finite numbers"});
    }
    const fs::path huge = mha(tmp, "h.mha", "ElementSpacing = 1 1 1e300\n");
    expectThrowWith<palp::FormatError>(
        [&] { palp::volume::readMetaImage(huge, {}); },
        {huge.string() + ": ElementSpacing (axis 2 step): expected a value in [0.001, 100] mm"});
    const fs::path zeroDir = mha(tmp, "zd.mha", "TransformMatrix = 1 0 0 0 0 0 0 0 1\n");
    expectThrowWith<palp::FormatError>(
        [&] { palp::volume::readMetaImage(zeroDir, {}); },
        {zeroDir.string() + ": TransformMatrix (axis 1): expected a finite non-zero direction",
         "found (0 0 0)"});
    const fs::path singular = mha(tmp, "sg.mha", "TransformMatrix = 1 0 0 1 0 0 0 0 1\n");
    expectThrowWith<palp::FormatError>(
        [&] { palp::volume::readMetaImage(singular, {}); },
        {singular.string() + ": TransformMatrix: expected three independent axis directions"});
    const fs::path far = mha(tmp, "o.mha", "Offset = 0 0 1e300\n");
    expectThrowWith<palp::FormatError>(
        [&] { palp::volume::readMetaImage(far, {}); },
        {far.string() + ": Offset (coordinate 2): expected a value in [-10000, 10000] mm",
         "found 1e+300"});
}

// ---------------------------------------------------------------------------------------------
// NIfTI-1, written field by field

struct NiftiFields {
    float pixdim[3] = {1, 1, 1};
    short qformCode = 0;
    short sformCode = 0;
    float srow[3][4] = {{1, 0, 0, 0}, {0, 1, 0, 0}, {0, 0, 1, 0}};
    float sclSlope = 0;
    float sclInter = 0;
    std::vector<float> values = {0, 1, 2, 3, 4, 5, 6, 7};
};

fs::path nifti(const TempDir& tmp, const std::string& name, const NiftiFields& f) {
    nifti_1_header h{};
    h.sizeof_hdr = 348;
    h.dim[0] = 3;
    h.dim[1] = h.dim[2] = h.dim[3] = 2;
    for (int d = 4; d < 8; ++d) h.dim[d] = 1;
    h.datatype = DT_FLOAT32;
    h.bitpix = 32;
    h.pixdim[0] = 1;
    for (int a = 0; a < 3; ++a) h.pixdim[a + 1] = f.pixdim[a];
    h.vox_offset = 352;
    h.scl_slope = f.sclSlope;
    h.scl_inter = f.sclInter;
    h.xyzt_units = NIFTI_UNITS_MM;
    h.qform_code = f.qformCode;
    h.sform_code = f.sformCode;
    std::memcpy(h.srow_x, f.srow[0], sizeof h.srow_x);
    std::memcpy(h.srow_y, f.srow[1], sizeof h.srow_y);
    std::memcpy(h.srow_z, f.srow[2], sizeof h.srow_z);
    std::memcpy(h.magic, "n+1", 4);
    std::string bytes(352, '\0');
    std::memcpy(bytes.data(), &h, sizeof h);
    const fs::path file = tmp / name;
    writeFile(file, bytes + floatsLE(f.values));
    return file;
}

TEST(NiftiChecks, ZeroOrNanPixdimIsRefusedNotReplacedByOne) {
    TempDir tmp;
    const float nan = std::numeric_limits<float>::quiet_NaN();
    for (const float bad : {0.0f, nan}) {
        NiftiFields f;
        f.pixdim[1] = bad;
        const fs::path file = nifti(tmp, "p.nii", f);
        expectThrowWith<palp::FormatError>(
            [&] { palp::volume::readNifti(file, {}); },
            {file.string() + ": pixdim[2]: expected a finite non-zero voxel width"});
    }
    // With a qform, nifticlib would silently take 1 for a negative width.
    NiftiFields q;
    q.qformCode = 1;
    q.pixdim[2] = -2;
    const fs::path file = nifti(tmp, "q.nii", q);
    expectThrowWith<palp::FormatError>(
        [&] { palp::volume::readNifti(file, {}); },
        {file.string() + ": pixdim[3] (qform): expected a finite positive voxel width",
         "found -2"});
    NiftiFields huge;
    huge.pixdim[0] = 1e30f;
    const fs::path far = nifti(tmp, "h.nii", huge);
    expectThrowWith<palp::FormatError>(
        [&] { palp::volume::readNifti(far, {}); },
        {far.string() + ": pixdim[1..3] (axis 0 step): expected a value in [0.001, 100] mm"});
}

TEST(NiftiChecks, PixdimIsUsedAsGiven) {
    TempDir tmp;
    NiftiFields f;
    f.pixdim[0] = 0.5f;
    f.pixdim[1] = 2;
    f.pixdim[2] = 3;
    const SliceStack st = palp::volume::readNifti(nifti(tmp, "ok.nii", f), {});
    ASSERT_EQ(st.slices.size(), 2u);
    EXPECT_NEAR(st.slices[0].colStep.norm(), 0.5e-3, 1e-15);
    EXPECT_NEAR(st.slices[0].rowStep.norm(), 2e-3, 1e-15);
    EXPECT_NEAR((st.slices[1].position - st.slices[0].position).norm(), 3e-3, 1e-15);
}

TEST(NiftiChecks, SingularSformIsRefused) {
    TempDir tmp;
    NiftiFields f;
    f.sformCode = 1;
    f.srow[0][1] = 1;  // columns 0 and 1 both (1, 0, 0)
    f.srow[1][1] = 0;
    const fs::path file = nifti(tmp, "s.nii", f);
    expectThrowWith<palp::FormatError>([&] { palp::volume::readNifti(file, {}); },
                                       {file.string() + ": srow_x/srow_y/srow_z (sform)",
                                        "expected three independent axis directions"});
}

TEST(NiftiChecks, SclSlopeFollowsTheStandard) {
    // scl_slope 0: not scaled (the standard); NaN: not scaled (nifticlib and nibabel read a
    // non-finite slope as 0); a finite slope scales, with a NaN intercept read as 0.
    TempDir tmp;
    struct Case {
        float slope, inter, expectAt7;
    };
    const float nan = std::numeric_limits<float>::quiet_NaN();
    for (const Case c : {Case{0, 5, 7}, Case{nan, 5, 7}, Case{2, 1, 15}, Case{2, nan, 14}}) {
        NiftiFields f;
        f.sclSlope = c.slope;
        f.sclInter = c.inter;
        const SliceStack st = palp::volume::readNifti(nifti(tmp, "sc.nii", f), {});
        EXPECT_EQ(st.slices.at(1).values.at(3), c.expectAt7) << c.slope << " " << c.inter;
    }
}

// ---------------------------------------------------------------------------------------------
// NaN and infinite voxels

TEST(VoxelValueChecks, NanOrInfiniteVoxelsAreRefusedAtLoadWithTheFileNamed) {
    TempDir tmp;
    const float nan = std::numeric_limits<float>::quiet_NaN();
    const float inf = std::numeric_limits<float>::infinity();
    const fs::path nanFile =
        nrrd(tmp, "nan.nrrd", "spacings: 1 1 1\n", eightFloats({0, 1, 2, 3, 4, nan, 6, 7}));
    expectThrowWith<palp::FormatError>(
        [&] { palp::volume::load({nanFile}); },
        {nanFile.string() + ": voxel (column 1, row 0, slice 1): expected a value in",
         "found nan"});
    const fs::path infFile = mha(tmp, "inf.mha", "", eightFloats({0, 1, 2, -inf, 4, 5, 6, 7}));
    expectThrowWith<palp::FormatError>(
        [&] { palp::volume::load({infFile}); },
        {infFile.string() + ": voxel (column 1, row 1, slice 0)", "found -inf"});
    NiftiFields f;
    f.sclSlope = 1e30f;  // finite data times a finite slope that overflows float
    f.values = {0, 0, 0, 0, 0, 0, 0, 1e10f};
    const fs::path big = nifti(tmp, "big.nii", f);
    expectThrowWith<palp::FormatError>(
        [&] { palp::volume::readStack({big}, {}); },
        {big.string() + ": voxel (column 1, row 1, slice 1)", "found inf"});
    f.values = {0, 0, 2, 0, 0, 0, 0, 0};  // finite in float, but not a volume value
    const fs::path large = nifti(tmp, "large.nii", f);
    expectThrowWith<palp::FormatError>(
        [&] { palp::volume::readStack({large}, {}); },
        {large.string() + ": voxel (column 0, row 1, slice 0)", "found 2e+30"});
}

TEST(VoxelValueChecks, ResampleRefusesNanValuesFromAnyCaller) {
    TempDir tmp;
    SliceStack st = palp::volume::readNrrd(nrrd(tmp, "ok.nrrd", "spacings: 1 1 1\n"), {});
    st.slices[0].values[2] = std::numeric_limits<float>::quiet_NaN();
    st.slices[0].source = "caller slice";
    expectThrowWith<palp::ValueError>([&] { palp::volume::resample(st); },
                                      {"caller slice: voxel (column 0, row 1, slice 0)"});
}

// ---------------------------------------------------------------------------------------------
// Load options: every value checked before any file is read

TEST(LoadOptionChecks, VoxelSizeBackgroundAndCropAreChecked) {
    TempDir tmp;
    const fs::path file = nrrd(tmp, "ok.nrrd", "spacings: 1 1 1\n");
    const double nan = std::numeric_limits<double>::quiet_NaN();
    const double inf = std::numeric_limits<double>::infinity();
    for (const double bad : {nan, inf, -inf, -1.0, 0.0, 1e300}) {
        palp::volume::LoadOptions o;
        o.resample.voxelSize = bad;
        expectThrowWith<palp::ValueError>(
            [&] { palp::volume::load({file}, o); },
            {"resample: voxel size: expected a value in [0.001, 100] mm"});
    }
    palp::volume::LoadOptions o;
    o.resample.backgroundThreshold = std::numeric_limits<float>::quiet_NaN();
    expectThrowWith<palp::ValueError>([&] { palp::volume::load({file}, o); },
                                      {"resample: background threshold", "found nan"});
    o = {};
    o.resample.crop = palp::volume::WorldBox{Eigen::Vector3d(0, nan, 0), Eigen::Vector3d::Ones()};
    expectThrowWith<palp::ValueError>([&] { palp::volume::load({file}, o); },
                                      {"resample: crop min[1]", "found nan"});
    o.resample.crop = palp::volume::WorldBox{Eigen::Vector3d::Ones(), Eigen::Vector3d::Zero()};
    expectThrowWith<palp::ValueError>([&] { palp::volume::load({file}, o); },
                                      {"resample: crop[0]: expected min <= max"});
    // The finest input spacing by default, and a voxel size in bounds, still load.
    EXPECT_NEAR(palp::volume::load({file}).voxelSize(), 1e-3, 1e-12);
    o = {};
    o.resample.voxelSize = 0.5e-3;
    EXPECT_NEAR(palp::volume::load({file}, o).voxelSize(), 0.5e-3, 1e-12);
}

}  // namespace
