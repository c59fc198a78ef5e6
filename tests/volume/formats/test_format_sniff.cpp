// Format detection by content: a file is read as what its bytes say, whatever its name; a NIfTI
// file under a name nifticlib will not open is refused saying what it is; NIfTI-2 is named
// NIfTI-2 in the slices, the grid's metadata and `palp info`; content palp cannot read is
// described. Every file is made at test time (a few bytes each).
#include <gtest/gtest.h>
#include <nifti2_io.h>

#include <cstring>
#include <string>
#include <vector>

#include "palp/base/error.h"
#include "palp/volume/load.h"
#include "test_support.h"

namespace {

namespace fs = std::filesystem;
using palp::test::deflateBytes;
using palp::test::expectThrowWith;
using palp::test::floatsLE;
using palp::test::TempDir;
using palp::test::writeFile;
using palp::volume::SliceStack;

const std::vector<float> kValues = {0, 1, 2, 3, 4, 5, 6, 7};  // 2x2x2, x fastest

/// A 2x2x2 float32 NIfTI-1 (.nii layout: header, 4 bytes of extension flags, data) with 1, 2,
/// 3 mm voxels and an sform that places voxel (0,0,0) at RAS (10, 20, 30) mm.
std::string nifti1Bytes() {
    nifti_1_header h{};
    h.sizeof_hdr = 348;
    h.dim[0] = 3;
    h.dim[1] = h.dim[2] = h.dim[3] = 2;
    for (int d = 4; d < 8; ++d) h.dim[d] = 1;
    h.datatype = DT_FLOAT32;
    h.bitpix = 32;
    h.pixdim[0] = 1;
    h.pixdim[1] = 1;
    h.pixdim[2] = 2;
    h.pixdim[3] = 3;
    h.vox_offset = 352;
    h.xyzt_units = NIFTI_UNITS_MM;
    h.sform_code = NIFTI_XFORM_SCANNER_ANAT;
    const float srow[3][4] = {{1, 0, 0, 10}, {0, 2, 0, 20}, {0, 0, 3, 30}};
    std::memcpy(h.srow_x, srow[0], sizeof h.srow_x);
    std::memcpy(h.srow_y, srow[1], sizeof h.srow_y);
    std::memcpy(h.srow_z, srow[2], sizeof h.srow_z);
    std::memcpy(h.magic, "n+1", 4);
    std::string bytes(352, '\0');
    std::memcpy(bytes.data(), &h, sizeof h);
    return bytes + floatsLE(kValues);
}

/// The same image as a NIfTI-2 file (540-byte header, data at 544).
std::string nifti2Bytes() {
    nifti_2_header h{};
    h.sizeof_hdr = 540;
    std::memcpy(h.magic, "n+2\0\r\n\032\n", 8);
    h.datatype = DT_FLOAT32;
    h.bitpix = 32;
    h.dim[0] = 3;
    h.dim[1] = h.dim[2] = h.dim[3] = 2;
    for (int d = 4; d < 8; ++d) h.dim[d] = 1;
    h.pixdim[0] = 1;
    h.pixdim[1] = 1;
    h.pixdim[2] = 2;
    h.pixdim[3] = 3;
    h.vox_offset = 544;
    h.xyzt_units = NIFTI_UNITS_MM;
    h.sform_code = NIFTI_XFORM_SCANNER_ANAT;
    const double srow[3][4] = {{1, 0, 0, 10}, {0, 2, 0, 20}, {0, 0, 3, 30}};
    std::memcpy(h.srow_x, srow[0], sizeof h.srow_x);
    std::memcpy(h.srow_y, srow[1], sizeof h.srow_y);
    std::memcpy(h.srow_z, srow[2], sizeof h.srow_z);
    std::string bytes(544, '\0');
    std::memcpy(bytes.data(), &h, sizeof h);
    return bytes + floatsLE(kValues);
}

/// The image both NIfTI files hold, checked in LPS metres: RAS (10, 20, 30) mm is LPS
/// (-10, -20, 30) mm, and the columns step -1 mm along x (RAS +x is LPS -x).
void expectTheKnownImage(const SliceStack& st) {
    ASSERT_EQ(st.slices.size(), 2u);
    EXPECT_LT((st.slices[0].position - Eigen::Vector3d(-10e-3, -20e-3, 30e-3)).norm(), 1e-12);
    EXPECT_LT((st.slices[0].colStep - Eigen::Vector3d(-1e-3, 0, 0)).norm(), 1e-12);
    EXPECT_LT((st.slices[0].rowStep - Eigen::Vector3d(0, -2e-3, 0)).norm(), 1e-12);
    EXPECT_EQ(st.slices[0].values, std::vector<float>(kValues.begin(), kValues.begin() + 4));
    EXPECT_EQ(st.slices[1].values, std::vector<float>(kValues.begin() + 4, kValues.end()));
}

TEST(FormatSniff, Nifti2IsNamedNifti2InSlicesMetadataAndInfo) {
    TempDir tmp;
    writeFile(tmp / "one.nii", nifti1Bytes());
    writeFile(tmp / "two.nii", nifti2Bytes());
    writeFile(tmp / "two.nii.gz", deflateBytes(nifti2Bytes(), true));
    const SliceStack one = palp::volume::readStack({tmp / "one.nii"}, {});
    expectTheKnownImage(one);
    EXPECT_EQ(one.info.sourceFormat, "NIfTI-1");
    for (const char* name : {"two.nii", "two.nii.gz"}) {
        const SliceStack two = palp::volume::readStack({tmp / name}, {});
        expectTheKnownImage(two);
        EXPECT_EQ(two.info.sourceFormat, "NIfTI-2") << name;
    }

    // The grid's metadata (palp:source_format) and both forms of `palp info` say NIfTI-2.
    palp::volume::LoadOptions opt;
    opt.resample.backgroundThreshold = -1;
    const palp::volume::Volume vol = palp::volume::load({tmp / "two.nii"}, opt);
    EXPECT_EQ(vol.info.sourceFormat, "NIfTI-2");
    palp::volume::save(vol, tmp / "two.vdb");
    EXPECT_EQ(palp::volume::loadVdb(tmp / "two.vdb").info.sourceFormat, "NIfTI-2");
    const std::string tool = "'" + palp::test::palpTool().string() + "' info ";
    auto r = palp::test::runCommand(tool + "--json '" + (tmp / "two.nii").string() + "'");
    ASSERT_EQ(r.exitCode, 0) << r.output;
    EXPECT_NE(r.output.find("\"format\": \"NIfTI-2\""), std::string::npos) << r.output;
    r = palp::test::runCommand(tool + "--json '" + (tmp / "two.vdb").string() + "'");
    ASSERT_EQ(r.exitCode, 0) << r.output;
    EXPECT_NE(r.output.find("\"source_format\": \"NIfTI-2\""), std::string::npos) << r.output;
}

TEST(FormatSniff, NiftiUnderAnotherNameIsRefusedSayingWhatItIs) {
    TempDir tmp;
    struct Case {
        std::string name, bytes, what;
    };
    const Case cases[] = {
        {"scan.dat", nifti1Bytes(), "found a NIfTI-1 file named 'scan.dat'"},
        {"scan", nifti2Bytes(), "found a NIfTI-2 file named 'scan'"},
        {"scan.bin", deflateBytes(nifti2Bytes(), true),
         "found a gzip-compressed NIfTI-2 file named"},
        {"scan.nrrd", nifti1Bytes(), "found a NIfTI-1 file named 'scan.nrrd'"},
    };
    for (const Case& c : cases) {
        const fs::path file = tmp / c.name;
        writeFile(file, c.bytes);
        EXPECT_EQ(palp::volume::detectFormat(file), palp::volume::Format::Nifti) << c.name;
        expectThrowWith<palp::FormatError>(
            [&] { palp::volume::readStack({file}, {}); },
            {file.string() + ": expected a NIfTI file named *.nii", c.what, "rename it"});
    }
    // Renamed as the message says, the same bytes read.
    fs::rename(tmp / "scan.dat", tmp / "scan.nii");
    expectTheKnownImage(palp::volume::readStack({tmp / "scan.nii"}, {}));
}

TEST(FormatSniff, ContentDecidesOverTheName) {
    TempDir tmp;
    // An NRRD named .nii is read as the NRRD it is.
    const std::string nrrd =
        "NRRD0004\ntype: float\ndimension: 3\nspace: left-posterior-superior\nsizes: 2 2 2\n"
        "space directions: (1,0,0) (0,1,0) (0,0,1)\nspace origin: (0,0,0)\nendian: little\n"
        "encoding: raw\n\n";
    writeFile(tmp / "nrrd.nii", nrrd + floatsLE(kValues));
    EXPECT_EQ(palp::volume::detectFormat(tmp / "nrrd.nii"), palp::volume::Format::Nrrd);
    const SliceStack st = palp::volume::readStack({tmp / "nrrd.nii"}, {});
    EXPECT_EQ(st.info.sourceFormat, "NRRD");
    ASSERT_EQ(st.slices.size(), 2u);
    EXPECT_EQ(st.slices[1].values, std::vector<float>(kValues.begin() + 4, kValues.end()));
    // A MetaImage header under no known name (and after a blank line) is one by its keys.
    writeFile(tmp / "header.txt",
              "\nNDims = 3\nDimSize = 2 2 2\nElementType = MET_FLOAT\nElementSpacing = 1 1 1\n"
              "ElementDataFile = LOCAL\n" +
                  floatsLE(kValues));
    EXPECT_EQ(palp::volume::detectFormat(tmp / "header.txt"), palp::volume::Format::MetaImage);
}

TEST(FormatSniff, WhatPalpCannotReadIsDescribed) {
    TempDir tmp;
    // One call per file.
    const auto check = [&](const std::string& name, const std::string& bytes,
                           const std::string& found) {
        writeFile(tmp / name, bytes);
        expectThrowWith<palp::FormatError>(
            [&] { palp::volume::readStack({tmp / name}, {}); },
            {(tmp / name).string() + ": expected a DICOM file", found});
    };
    check("notes.gz", deflateBytes("plain text, compressed\n", true),
          "found a gzip stream palp cannot read");
    check("picture.xyz", std::string("\x89PNG\r\n\x1a\n", 8) + std::string(64, '\0'),
          "found an unknown format (its first bytes match none of them and its name says "
          "nothing)");
    // Named .nii but without a NIfTI header: the message says what is missing.
    writeFile(tmp / "zeros.nii", std::string(400, '\0'));
    expectThrowWith<palp::FormatError>(
        [&] { palp::volume::readStack({tmp / "zeros.nii"}, {}); },
        {(tmp / "zeros.nii").string() + ": expected a NIfTI-1 or NIfTI-2 header",
         "found a file without the NIfTI magic"});
}

}  // namespace
