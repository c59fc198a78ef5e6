// The same scan through different readers and DICOM transfer syntaxes must give the same
// geometry and the same values.
#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <cstdio>

#include "palp/volume/load.h"
#include "test_support.h"

namespace {

namespace fs = std::filesystem;
using palp::test::runCommand;

/// Unzips the DICOM member of mr-one-volume-many-formats into @p dir; returns the folder.
fs::path unzipDicom(const fs::path& set, const palp::test::TempDir& tmp) {
    const auto r = runCommand("unzip -q -o '" + (set / "DICOM.zip").string() + "' -d '" +
                              tmp.path().string() + "'");
    EXPECT_EQ(r.exitCode, 0) << r.output;
    return tmp.path();
}

struct Comparison {
    double maxTransformDiff = 0;  // metres, between index->world maps at the box corners
    double maxValueDiff = 0;
    std::uint64_t compared = 0;
};

Comparison compareVolumes(const palp::volume::Volume& a, const palp::volume::Volume& b) {
    Comparison c;
    const auto& ta = a.grid->transform();
    const auto& tb = b.grid->transform();
    for (const openvdb::Vec3d ijk : {openvdb::Vec3d(0, 0, 0), openvdb::Vec3d(100, 100, 100)}) {
        c.maxTransformDiff =
            std::max(c.maxTransformDiff, (ta.indexToWorld(ijk) - tb.indexToWorld(ijk)).length());
    }
    const auto acc = b.grid->getConstAccessor();
    for (auto it = a.grid->cbeginValueOn(); it; ++it) {
        c.maxValueDiff = std::max(c.maxValueDiff,
                                  static_cast<double>(std::abs(*it - acc.getValue(it.getCoord()))));
        ++c.compared;
    }
    // And the other way round, so voxels active only in b count too.
    const auto accA = a.grid->getConstAccessor();
    for (auto it = b.grid->cbeginValueOn(); it; ++it) {
        c.maxValueDiff = std::max(
            c.maxValueDiff, static_cast<double>(std::abs(*it - accA.getValue(it.getCoord()))));
    }
    return c;
}

TEST(CrossFormat, DicomNrrdAndMetaImageAgree) {
    PALP_REQUIRE_DATA(set, "mr-one-volume-many-formats");
    if (!palp::test::haveProgram("unzip")) GTEST_SKIP() << "unzip not installed";
    palp::test::TempDir tmp;
    const fs::path dicom = unzipDicom(set, tmp);
    palp::volume::LoadOptions opt;
    opt.resample.voxelSize = 1.0e-3;
    const auto fromDicom = palp::volume::load({dicom}, opt);
    const auto fromNrrd = palp::volume::load({set / "nrrd.nhdr"}, opt);
    const auto fromMha = palp::volume::load({set / "mha.mha"}, opt);
    ASSERT_GT(fromDicom.grid->activeVoxelCount(), 10000u);
    for (const auto* other : {&fromNrrd, &fromMha}) {
        const Comparison c = compareVolumes(fromDicom, *other);
        EXPECT_LT(c.maxTransformDiff, 1e-6) << other->info.sourceFormat;
        // Same stored integers, same rescale: identical up to float rounding of the blend weights
        // (source geometry agrees to ~1e-6 m, i.e. 1e-6 of a voxel).
        EXPECT_LT(c.maxValueDiff, 0.05) << other->info.sourceFormat;
        EXPECT_EQ(c.compared, fromDicom.grid->activeVoxelCount());
        std::printf("DICOM vs %s: transform %.3g m, values %.3g over %llu voxels\n",
                    other->info.sourceFormat.c_str(), c.maxTransformDiff, c.maxValueDiff,
                    static_cast<unsigned long long>(c.compared));
    }
    // The slices themselves (the files may store rows or slices in opposite orders): the world
    // boxes of all pixel centres agree within 1e-6 m.
    const auto boxOf = [](const palp::volume::SliceStack& st) {
        Eigen::AlignedBox3d box;
        for (const auto& s : st.slices)
            for (int a : {0, 1})
                for (int b : {0, 1})
                    box.extend(s.position + a * (s.cols - 1) * s.colStep +
                               b * (s.rows - 1) * s.rowStep);
        return box;
    };
    const auto bd = boxOf(palp::volume::readStack({dicom}, opt));
    for (const fs::path& f : {set / "nrrd.nhdr", set / "mha.mha"}) {
        const auto bo = boxOf(palp::volume::readStack({f}, opt));
        EXPECT_LT((bd.min() - bo.min()).norm(), 1e-6) << f;
        EXPECT_LT((bd.max() - bo.max()).norm(), 1e-6) << f;
    }
}

// Every lossless transfer syntax that Debian's GDCM writes must decode to the same values.
TEST(CrossFormat, LosslessTransferSyntaxesDecodeIdentically) {
    PALP_REQUIRE_DATA(set, "mr-one-volume-many-formats");
    if (!palp::test::haveProgram("gdcmconv") || !palp::test::haveProgram("unzip")) {
        GTEST_SKIP() << "gdcmconv (libgdcm-tools) or unzip not installed";
    }
    palp::test::TempDir tmp;
    const fs::path dicom = unzipDicom(set, tmp);
    std::vector<fs::path> files;
    for (const auto& e : fs::recursive_directory_iterator(dicom)) {
        if (e.is_regular_file() &&
            palp::volume::detectFormat(e.path()) == palp::volume::Format::Dicom &&
            e.path().filename().string().front() != '.') {
            files.push_back(e.path());
        }
    }
    ASSERT_FALSE(files.empty());
    const palp::volume::LoadOptions opt;
    const auto reference = palp::volume::readStack({dicom}, opt);
    // flag, transfer syntax
    const std::vector<std::pair<std::string, std::string>> syntaxes{
        {"--implicit", "1.2.840.10008.1.2"},  {"--deflated", "1.2.840.10008.1.2.1.99"},
        {"--jpeg", "1.2.840.10008.1.2.4.70"}, {"--jpegls", "1.2.840.10008.1.2.4.80"},
        {"--j2k", "1.2.840.10008.1.2.4.90"},  {"--rle", "1.2.840.10008.1.2.5"}};
    for (const auto& [flag, uid] : syntaxes) {
        const fs::path out = tmp.path() / ("ts" + flag);
        fs::create_directories(out);
        for (const fs::path& f : files) {
            const auto r = runCommand("gdcmconv " + flag + " '" + f.string() + "' '" +
                                      (out / f.filename()).string() + "'");
            ASSERT_EQ(r.exitCode, 0) << flag << ": " << r.output;
        }
        const auto dump = runCommand("gdcmdump '" + (out / files.front().filename()).string() +
                                     "' | grep '(0002,0010)'");
        ASSERT_NE(dump.output.find(uid), std::string::npos)
            << flag << " did not produce " << uid << ": " << dump.output;
        const auto stack = palp::volume::readStack({out}, opt);
        ASSERT_EQ(stack.slices.size(), reference.slices.size()) << flag;
        for (std::size_t k = 0; k < stack.slices.size(); ++k) {
            ASSERT_EQ(stack.slices[k].values, reference.slices[k].values) << flag << " slice " << k;
            ASSERT_LT((stack.slices[k].position - reference.slices[k].position).norm(), 1e-9)
                << flag;
        }
    }
}

}  // namespace
