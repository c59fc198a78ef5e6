// Tests of the NIfTI, NRRD and MetaImage readers: real files against nibabel, the same scan in
// two formats against each other, synthetic files with known geometry and values, and bad
// inputs (right exception, message naming the file with expected/found, nothing written).
#include <gtest/gtest.h>
#include <openvdb/tools/Interpolation.h>

#include <cmath>
#include <cstring>
#include <fstream>
#include <sstream>

#include "formats/formats.h"
#include "formats/header_parsers.h"
#include "palp/base/error.h"
#include "palp/volume/load.h"
#include "palp/volume/resample.h"
#include "test_support.h"

namespace {

namespace fs = std::filesystem;
using palp::test::deflateBytes;
using palp::test::expectThrowWith;
using palp::test::floatsLE;
using palp::test::TempDir;
using palp::test::writeFile;
using palp::volume::LoadOptions;
using palp::volume::SliceStack;

std::string int16BE(const std::vector<std::int16_t>& v) {
    std::string s;
    for (const std::int16_t x : v) {
        const auto u = static_cast<std::uint16_t>(x);
        s.push_back(static_cast<char>(u >> 8));
        s.push_back(static_cast<char>(u & 0xff));
    }
    return s;
}

double stackSum(const SliceStack& st) {
    double s = 0;
    for (const auto& sl : st.slices)
        for (const float v : sl.values) s += v;
    return s;
}

float voxel(const SliceStack& st, int i, int j, int k) {
    const auto& sl = st.slices.at(static_cast<std::size_t>(k));
    return sl.values.at(static_cast<std::size_t>(j * sl.cols + i));
}

// ----------------------------------------------------------------------------------------------
// NIfTI against nibabel

struct NibabelResult {
    std::vector<std::int64_t> shape;
    Eigen::Matrix4d affine;
    double sum = 0;
    std::vector<double> probes;  // values at the probe indices
};

bool haveNibabel() {
    return palp::test::runCommand("/usr/bin/python3 -c 'import nibabel' >/dev/null 2>&1")
               .exitCode == 0;
}

/// Runs nibabel on @p file, volume @p t (-1: 3D), and returns its affine, sum and probe values.
NibabelResult nibabel(const fs::path& file, int t, const std::vector<std::array<int, 3>>& probes) {
    TempDir tmp;
    std::ostringstream py;
    py << "import sys, nibabel as nib, numpy as np\n"
       << "im = nib.load(sys.argv[1]); t = int(sys.argv[2])\n"
       << "d = np.asarray(im.get_fdata(dtype=np.float64))\n"
       << "if t >= 0: d = d[..., t]\n"
       << "print(' '.join(str(x) for x in d.shape))\n"
       << "print(' '.join(repr(float(x)) for x in im.affine.flatten()))\n"
       << "print(repr(float(d.sum())))\n"
       << "probes = [";
    for (const auto& p : probes) py << "(" << p[0] << "," << p[1] << "," << p[2] << "),";
    py << "]\nprint(' '.join(repr(float(d[p])) for p in probes))\n";
    writeFile(tmp / "oracle.py", py.str());
    const auto r = palp::test::runCommand("/usr/bin/python3 " + (tmp / "oracle.py").string() + " " +
                                          file.string() + " " + std::to_string(t));
    NibabelResult out;
    EXPECT_EQ(r.exitCode, 0) << r.output;
    std::istringstream in(r.output);
    std::string line;
    std::getline(in, line);
    std::istringstream ls(line);
    for (std::int64_t v; ls >> v;) out.shape.push_back(v);
    for (int i = 0; i < 16; ++i) in >> out.affine(i / 4, i % 4);
    in >> out.sum;
    for (std::size_t i = 0; i < probes.size(); ++i) {
        double v = 0;
        in >> v;
        out.probes.push_back(v);
    }
    return out;
}

/// Our stack's geometry against nibabel's RAS mm affine.
void expectGeometryMatches(const SliceStack& st, const Eigen::Matrix4d& rasMm) {
    Eigen::Matrix4d lps = rasMm;
    lps.row(0) *= -1;
    lps.row(1) *= -1;
    const Eigen::Matrix3d axes = lps.topLeftCorner<3, 3>() * 1e-3;
    const Eigen::Vector3d origin = lps.topRightCorner<3, 1>() * 1e-3;
    for (std::size_t k = 0; k < st.slices.size(); ++k) {
        const auto& s = st.slices[k];
        EXPECT_LT((s.position - (origin + static_cast<double>(k) * axes.col(2))).norm(), 1e-9)
            << "slice " << k;
        EXPECT_LT((s.colStep - axes.col(0)).norm(), 1e-9);
        EXPECT_LT((s.rowStep - axes.col(1)).norm(), 1e-9);
    }
}

TEST(Nifti, BigEndianAnatomicalMatchesNibabel) {
    PALP_REQUIRE_DATA(dir, "nifti-mr");
    if (!haveNibabel()) GTEST_SKIP() << "/usr/bin/python3 with nibabel not available";
    const fs::path file = dir / "anatomical.nii";
    const std::vector<std::array<int, 3>> probes{
        {10, 11, 12}, {16, 20, 12}, {0, 0, 0}, {32, 40, 24}};
    const NibabelResult ref = nibabel(file, -1, probes);
    const SliceStack st = palp::volume::readNifti(file, {});
    ASSERT_EQ(ref.shape, (std::vector<std::int64_t>{33, 41, 25}));
    ASSERT_EQ(st.slices.size(), 25u);
    EXPECT_EQ(st.slices[0].cols, 33);
    EXPECT_EQ(st.slices[0].rows, 41);
    EXPECT_EQ(st.info.sourceFormat, "NIfTI-1");
    EXPECT_EQ(st.info.timePointCount, 1);
    EXPECT_EQ(st.info.timePoint, -1);
    EXPECT_EQ(st.info.originalDims, (std::array<std::int64_t, 3>{33, 41, 25}));
    EXPECT_NEAR(st.info.originalSpacing[0], 2e-3, 1e-12);
    expectGeometryMatches(st, ref.affine);
    // The first voxel in LPS metres: nibabel's (32, -40, -16) mm RAS -> (-0.032, 0.040, -0.016).
    EXPECT_LT((st.slices[0].position - Eigen::Vector3d(-0.032, 0.040, -0.016)).norm(), 1e-12);
    EXPECT_DOUBLE_EQ(stackSum(st), ref.sum);
    for (std::size_t p = 0; p < probes.size(); ++p) {
        EXPECT_EQ(voxel(st, probes[p][0], probes[p][1], probes[p][2]), ref.probes[p])
            << "probe " << p;
    }
    EXPECT_EQ(voxel(st, 10, 11, 12), 9318.0f);  // big-endian int16 decoded (nibabel says 9318)
}

TEST(Nifti, Gzip4DNeedsAVolumeAndMatchesNibabel) {
    PALP_REQUIRE_DATA(dir, "nifti-mr");
    const fs::path file = dir / "example4d.nii.gz";
    expectThrowWith<palp::ValueError>(
        [&] { palp::volume::readNifti(file, {}); },
        {file.string() +
         ": expected a time point to choose one of the 2 time points (0-1), found none"});
    LoadOptions bad;
    bad.timePoint = 2;
    expectThrowWith<palp::ValueError>([&] { palp::volume::readNifti(file, bad); },
                                      {file.string(), "found 2"});

    if (!haveNibabel()) GTEST_SKIP() << "/usr/bin/python3 with nibabel not available";
    const std::vector<std::array<int, 3>> probes{
        {64, 48, 12}, {30, 40, 10}, {100, 20, 5}, {60, 70, 20}};
    LoadOptions o0, o1;
    o0.timePoint = 0;
    o1.timePoint = 1;
    const SliceStack v0 = palp::volume::readNifti(file, o0);
    const SliceStack v1 = palp::volume::readNifti(file, o1);
    const NibabelResult r0 = nibabel(file, 0, probes);
    const NibabelResult r1 = nibabel(file, 1, probes);
    ASSERT_EQ(v1.slices.size(), 24u);
    EXPECT_EQ(v1.slices[0].cols, 128);
    EXPECT_EQ(v1.slices[0].rows, 96);
    EXPECT_EQ(v1.info.timePoint, 1);
    EXPECT_EQ(v1.info.timePointCount, 2);
    EXPECT_EQ(v1.info.sourceFormat, "NIfTI-1");
    expectGeometryMatches(v1, r1.affine);  // sform (oblique), RAS -> LPS
    EXPECT_DOUBLE_EQ(stackSum(v0), r0.sum);
    EXPECT_DOUBLE_EQ(stackSum(v1), r1.sum);
    EXPECT_NE(stackSum(v0), stackSum(v1));
    for (std::size_t p = 0; p < probes.size(); ++p) {
        EXPECT_EQ(voxel(v0, probes[p][0], probes[p][1], probes[p][2]), r0.probes[p])
            << "probe " << p;
        EXPECT_EQ(voxel(v1, probes[p][0], probes[p][1], probes[p][2]), r1.probes[p])
            << "probe " << p;
    }
}

TEST(Nifti, ShortUncompressedFileIsRefusedBeforeLoading) {
    PALP_REQUIRE_DATA(dir, "nifti-mr");
    TempDir tmp;
    std::ifstream in(dir / "anatomical.nii", std::ios::binary);
    std::string bytes((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
    bytes.resize(bytes.size() - 1000);
    const fs::path file = tmp / "short.nii";
    writeFile(file, bytes);
    // 33*41*25*2 = 67650 bytes of data after the 352-byte header.
    expectThrowWith<palp::FormatError>(
        [&] { palp::volume::readNifti(file, {}); },
        {file.string() + ": expected 67650 bytes of voxel data after the header, found 66650"});
}

// ----------------------------------------------------------------------------------------------
// The same scan as NRRD (detached gzip) and MetaImage (zlib)

TEST(NrrdVsMetaImage, SameScanGivesTheSameWorldAndValues) {
    PALP_REQUIRE_DATA(dir, "mr-one-volume-many-formats");
    const SliceStack a = palp::volume::readNrrd(dir / "nrrd.nhdr", {});
    const SliceStack b = palp::volume::readMetaImage(dir / "mha.mha", {});
    ASSERT_EQ(a.slices.size(), 37u);
    ASSERT_EQ(b.slices.size(), 37u);
    EXPECT_EQ(a.info.sourceFormat, "NRRD");
    EXPECT_EQ(b.info.sourceFormat, "MetaImage");
    for (std::size_t k = 0; k < a.slices.size(); ++k) {
        const auto& sa = a.slices[k];
        const auto& sb = b.slices[k];
        ASSERT_EQ(sa.cols, 64);
        ASSERT_EQ(sa.rows, 64);
        ASSERT_EQ(sb.cols, 64);
        EXPECT_LT((sa.position - sb.position).norm(), 1e-6) << "slice " << k;
        EXPECT_LT((sa.colStep - sb.colStep).norm(), 1e-6);
        EXPECT_LT((sa.rowStep - sb.rowStep).norm(), 1e-6);
        EXPECT_EQ(sa.values, sb.values) << "slice " << k;
    }
    // From the NRRD header: origin (108.281, -82.3795, -47.8356) mm RAS, steps 3.4375 / 3.8 mm.
    EXPECT_LT((a.slices[0].position - Eigen::Vector3d(-0.108281, 0.0823795, -0.0478356)).norm(),
              1e-12);
    EXPECT_LT((a.slices[0].colStep - Eigen::Vector3d(3.4375e-3, 0, 0)).norm(), 1e-12);
    EXPECT_LT((a.slices[0].rowStep - Eigen::Vector3d(0, -3.4375e-3, 0)).norm(), 1e-12);
    EXPECT_LT((a.slices[1].position - a.slices[0].position - Eigen::Vector3d(0, 0, 3.8e-3)).norm(),
              1e-12);
    EXPECT_GT(stackSum(a), 0.0);
}

// ----------------------------------------------------------------------------------------------
// Synthetic NRRD

double linearField(int i, int j, int k) { return 100.0 + i + 10.0 * j + 100.0 * k; }

std::vector<float> fieldValues(int nx, int ny, int nz) {
    std::vector<float> v;
    for (int k = 0; k < nz; ++k)
        for (int j = 0; j < ny; ++j)
            for (int i = 0; i < nx; ++i) v.push_back(static_cast<float>(linearField(i, j, k)));
    return v;
}

TEST(Nrrd, AttachedRawKnownAffineResamplesToKnownValues) {
    TempDir tmp;
    const fs::path file = tmp / "known.nrrd";
    const std::string header =
        "NRRD0004\n# a comment\ntype: float\ndimension: 3\nspace: left-posterior-superior\n"
        "sizes: 4 3 5\nspace directions: (2,0,0) (0,3,0) (0,0,4)\nspace origin: (10,-20,30)\n"
        "kinds: domain domain domain\nendian: little\nencoding: raw\ncontent: known field\nsome "
        "key:=ignored\n\n";
    writeFile(file, header + floatsLE(fieldValues(4, 3, 5)));
    const SliceStack st = palp::volume::readNrrd(file, {});
    ASSERT_EQ(st.slices.size(), 5u);
    EXPECT_EQ(st.info.sourceDescription, "known field");
    for (int k = 0; k < 5; ++k) {
        EXPECT_LT((st.slices[static_cast<std::size_t>(k)].position -
                   Eigen::Vector3d(10e-3, -20e-3, (30.0 + 4 * k) * 1e-3))
                      .norm(),
                  1e-15);
        for (int j = 0; j < 3; ++j)
            for (int i = 0; i < 4; ++i) EXPECT_EQ(voxel(st, i, j, k), linearField(i, j, k));
    }
    palp::volume::ResampleOptions ro;
    ro.voxelSize = 1e-3;
    const palp::volume::Volume vol = palp::volume::resample(st, ro);
    openvdb::tools::GridSampler<openvdb::FloatGrid, openvdb::tools::BoxSampler> sampler(*vol.grid);
    // World (mm, LPS) -> value: linear in index, so exact at source voxels and between them.
    auto expected = [](double x, double y, double z) {
        return linearField(0, 0, 0) + (x - 10) / 2 + 10 * (y + 20) / 3 + 100 * (z - 30) / 4;
    };
    const std::vector<Eigen::Vector3d> pts{
        {10, -20, 30}, {16, -14, 46}, {11, -19, 31}, {13, -17, 41}, {12, -15, 38}};
    for (const auto& p : pts) {
        const float v = sampler.wsSample(openvdb::Vec3d(p.x() * 1e-3, p.y() * 1e-3, p.z() * 1e-3));
        EXPECT_NEAR(v, expected(p.x(), p.y(), p.z()), 1e-3) << p.transpose();
    }
}

TEST(Nrrd, RasObliqueDirectionsBecomeLps) {
    TempDir tmp;
    const fs::path file = tmp / "ras.nrrd";
    const double c = std::cos(0.5), s = std::sin(0.5);
    std::ostringstream h;
    h.precision(17);
    h << "NRRD0005\ntype: uint8\ndimension: 3\nspace: RAS\nsizes: 2 2 2\n"
      << "space directions: (" << c << "," << s << ",0) (" << -s << "," << c << ",0) (0,0,1.5)\n"
      << "space origin: (1,2,3)\nspace units: \"mm\" \"mm\" \"mm\"\nencoding: raw\n\n";
    writeFile(file, h.str() + std::string("\x01\x02\x03\x04\x05\x06\x07\x08", 8));
    const SliceStack st = palp::volume::readNrrd(file, {});
    EXPECT_LT((st.slices[0].position - Eigen::Vector3d(-1e-3, -2e-3, 3e-3)).norm(), 1e-15);
    EXPECT_LT((st.slices[0].colStep - Eigen::Vector3d(-c, -s, 0) * 1e-3).norm(), 1e-15);
    EXPECT_LT((st.slices[0].rowStep - Eigen::Vector3d(s, -c, 0) * 1e-3).norm(), 1e-15);
    EXPECT_LT((st.slices[1].position - Eigen::Vector3d(-1e-3, -2e-3, 4.5e-3)).norm(), 1e-15);
    EXPECT_EQ(voxel(st, 1, 1, 1), 8.0f);
    EXPECT_EQ(voxel(st, 1, 0, 1), 6.0f);
}

TEST(Nrrd, BigEndianInt16AndSpacingsFallback) {
    TempDir tmp;
    const fs::path file = tmp / "be.nrrd";
    const std::vector<std::int16_t> v{-32768, -1, 0, 1, 258, 32767, -300, 1234};
    writeFile(file,
              "NRRD0004\ntype: short\ndimension: 3\nsizes: 2 2 2\nspacings: 0.5 0.25 2\n"
              "axis mins: 1 2 3\nendian: big\nencoding: raw\n\n" +
                  int16BE(v));
    const SliceStack st = palp::volume::readNrrd(file, {});
    for (int n = 0; n < 8; ++n)
        EXPECT_EQ(voxel(st, n % 2, (n / 2) % 2, n / 4),
                  static_cast<float>(v[static_cast<std::size_t>(n)]));
    EXPECT_LT((st.slices[0].colStep - Eigen::Vector3d(0.5e-3, 0, 0)).norm(), 1e-15);
    EXPECT_LT((st.slices[0].rowStep - Eigen::Vector3d(0, 0.25e-3, 0)).norm(), 1e-15);
    EXPECT_LT((st.slices[1].position - Eigen::Vector3d(1e-3, 2e-3, 5e-3)).norm(), 1e-15);
}

TEST(Nrrd, DetachedGzipAsciiAnd4D) {
    TempDir tmp;
    // 4D: time axis last, gzip detached, with 'none' for the time axis.
    std::vector<float> vals = fieldValues(3, 2, 2);
    std::vector<float> second = vals;
    for (float& x : second) x += 1000;
    vals.insert(vals.end(), second.begin(), second.end());
    writeFile(tmp / "d.raw.gz", deflateBytes(floatsLE(vals), true));
    writeFile(tmp / "d.nhdr",
              "NRRD0005\ntype: float\ndimension: 4\nspace: LPS\nsizes: 3 2 2 2\n"
              "space directions: (1,0,0) (0,1,0) (0,0,1) none\nkinds: space space space time\n"
              "endian: little\nencoding: gzip\ndata file: d.raw.gz\n");
    expectThrowWith<palp::ValueError>(
        [&] { palp::volume::readNrrd(tmp / "d.nhdr", {}); },
        {"d.nhdr: expected a time point to choose one of the 2 time points (0-1), found none"});
    LoadOptions o;
    o.timePoint = 1;
    const SliceStack st = palp::volume::readNrrd(tmp / "d.nhdr", o);
    EXPECT_EQ(st.info.timePointCount, 2);
    EXPECT_EQ(voxel(st, 2, 1, 1), static_cast<float>(linearField(2, 1, 1) + 1000));

    // ASCII with a line skip in a detached file.
    writeFile(tmp / "a.txt", "junk line\n1 2 3\n4,5,6\n7 8\n");
    writeFile(tmp / "a.nhdr",
              "NRRD0004\ntype: double\ndimension: 3\nsizes: 2 2 2\nencoding: ascii\n"
              "data file: a.txt\nline skip: 1\n");
    const SliceStack sa = palp::volume::readNrrd(tmp / "a.nhdr", {});
    EXPECT_EQ(voxel(sa, 1, 1, 1), 8.0f);
    EXPECT_EQ(voxel(sa, 0, 1, 0), 3.0f);
}

TEST(Nrrd, HugeSizesAreRefusedBeforeAllocating) {
    TempDir tmp;
    const fs::path file = tmp / "huge.nrrd";
    writeFile(file,
              "NRRD0004\ntype: short\ndimension: 3\nsizes: 100000 100000 100000\nendian: little\n"
              "encoding: raw\n\n\x01\x02");
    expectThrowWith<palp::ValueError>(
        [&] { palp::volume::readNrrd(file, {}); },
        {file.string() + ": expected at most 8589934592 bytes of voxel data",
         "100000 x 100000 x 100000 x 2 bytes = 2000000000000000"});
    // Overflowing products are refused too.
    writeFile(file,
              "NRRD0004\ntype: double\ndimension: 4\nsizes: 4294967296 4294967296 4294967296 2\n"
              "endian: little\nencoding: gzip\n\n");
    expectThrowWith<palp::ValueError>([&] { palp::volume::readNrrd(file, {}); },
                                      {file.string(), "more than 2^64"});
}

TEST(Nrrd, ShortRawFileIsRefused) {
    TempDir tmp;
    writeFile(tmp / "s.raw", std::string(100, '\0'));
    writeFile(tmp / "s.nhdr",
              "NRRD0004\ntype: float\ndimension: 3\nsizes: 2 3 5\nendian: little\n"
              "encoding: raw\ndata file: s.raw\n");
    expectThrowWith<palp::FormatError>(
        [&] { palp::volume::readNrrd(tmp / "s.nhdr", {}); },
        {(tmp / "s.raw").string() + ": expected 120 bytes of voxel data after the header",
         "found 100"});
}

TEST(Nrrd, TruncatedAndOverlongGzipAreRefused) {
    TempDir tmp;
    const std::string data = floatsLE(fieldValues(8, 8, 8));
    const std::string gz = deflateBytes(data, true);
    const std::string header =
        "NRRD0004\ntype: float\ndimension: 3\nsizes: 8 8 8\nendian: little\nencoding: gzip\n\n";
    writeFile(tmp / "t.nrrd", header + gz.substr(0, gz.size() / 2));
    expectThrowWith<palp::FormatError>(
        [&] { palp::volume::readNrrd(tmp / "t.nrrd", {}); },
        {(tmp / "t.nrrd").string() + ": expected 2048 bytes of decompressed voxel data",
         "truncated"});
    // Header says fewer samples than the stream holds.
    writeFile(
        tmp / "l.nrrd",
        "NRRD0004\ntype: float\ndimension: 3\nsizes: 8 8 7\nendian: little\nencoding: gzip\n\n" +
            gz);
    expectThrowWith<palp::FormatError>(
        [&] { palp::volume::readNrrd(tmp / "l.nrrd", {}); },
        {(tmp / "l.nrrd").string() +
         ": expected 1792 bytes of decompressed voxel data, found more"});
    // The intact stream reads back.
    writeFile(tmp / "ok.nrrd", header + gz);
    EXPECT_EQ(voxel(palp::volume::readNrrd(tmp / "ok.nrrd", {}), 7, 6, 5),
              static_cast<float>(linearField(7, 6, 5)));
}

TEST(Nrrd, MalformedHeadersNameFileLineAndExpectation) {
    TempDir tmp;
    const fs::path file = tmp / "bad.nrrd";
    writeFile(file, "NRRD0004\ntype: complex\ndimension: 3\nsizes: 2 2 2\nencoding: raw\n\n");
    expectThrowWith<palp::FormatError>(
        [&] { palp::volume::readNrrd(file, {}); },
        {file.string() + ": line 2: expected 'type' with a scalar type", "found 'complex'"});
    writeFile(file,
              "NRRD0004\ntype: uchar\ndimension: 3\nsizes: 2 2 2\nencoding: raw\nfoo: bar\n\n");
    expectThrowWith<palp::FormatError>(
        [&] { palp::volume::readNrrd(file, {}); },
        {file.string() + ": line 6: expected a NRRD field, found 'foo'"});
    writeFile(file, "NRRD0004\ntype: uchar\ndimension: 3\nsizes: 2 0 2\nencoding: raw\n\n");
    expectThrowWith<palp::FormatError>(
        [&] { palp::volume::readNrrd(file, {}); },
        {file.string() + ": line 4: expected 'sizes' with 3 positive integers, found '2 0 2'"});
    writeFile(file, "NRRD0004\ntype: short\ndimension: 3\nsizes: 2 2 2\nencoding: raw\n\n");
    expectThrowWith<palp::FormatError>([&] { palp::volume::readNrrd(file, {}); },
                                       {file.string() + ": expected an 'endian' field"});
    writeFile(file, "NRRD0004\ntype: uchar\ndimension: 3\nsizes: 2 2 2\nencoding: bzip2\n\n");
    expectThrowWith<palp::FormatError>([&] { palp::volume::readNrrd(file, {}); },
                                       {file.string() + ": line 5: expected 'encoding'"});
    writeFile(file,
              "NRRD0004\ntype: uchar\ndimension: 3\nsizes: 2 2 2\nspace: RAS\n"
              "space directions: (1,0,0) (0,1) (0,0,1)\nencoding: raw\n\n");
    expectThrowWith<palp::FormatError>(
        [&] { palp::volume::readNrrd(file, {}); },
        {file.string() + ": line 6: expected 'space directions' with 3 vectors of 3 numbers"});
    writeFile(file, "P5 2 2\n");
    expectThrowWith<palp::FormatError>(
        [&] { palp::volume::readNrrd(file, {}); },
        {file.string() + ": line 1: expected the magic 'NRRD0001' to 'NRRD0005'"});
    writeFile(
        file,
        "NRRD0004\ntype: uchar\ndimension: 3\nsizes: 2 2 2\nencoding: raw\ndata file: LIST\n");
    expectThrowWith<palp::FormatError>([&] { palp::volume::readNrrd(file, {}); },
                                       {file.string() + ": line 6", "LIST"});
}

// ----------------------------------------------------------------------------------------------
// Synthetic MetaImage

TEST(MetaImage, MhdRawPairWithDirectionsAndBigEndian) {
    TempDir tmp;
    std::vector<std::int16_t> v;
    for (int n = 0; n < 3 * 2 * 4; ++n) v.push_back(static_cast<std::int16_t>(n * 37 - 400));
    writeFile(tmp / "img.raw", int16BE(v));
    // Axis 0 along +y, axis 1 along -x (column-major direction cosines), axis 2 along z.
    writeFile(tmp / "img.mhd",
              "ObjectType = Image\nNDims = 3\nBinaryData = True\nElementByteOrderMSB = True\n"
              "TransformMatrix = 0 1 0 -1 0 0 0 0 1\nOffset = 5 -6 7\nAnatomicalOrientation = RAI\n"
              "ElementSpacing = 0.5 2 3\nDimSize = 3 2 4\nElementType = MET_SHORT\n"
              "ElementDataFile = img.raw\n");
    const SliceStack st = palp::volume::readMetaImage(tmp / "img.mhd", {});
    ASSERT_EQ(st.slices.size(), 4u);
    EXPECT_LT((st.slices[0].colStep - Eigen::Vector3d(0, 0.5e-3, 0)).norm(), 1e-15);
    EXPECT_LT((st.slices[0].rowStep - Eigen::Vector3d(-2e-3, 0, 0)).norm(), 1e-15);
    EXPECT_LT((st.slices[2].position - Eigen::Vector3d(5e-3, -6e-3, 13e-3)).norm(), 1e-15);
    for (int n = 0; n < 24; ++n)
        EXPECT_EQ(voxel(st, n % 3, (n / 3) % 2, n / 6),
                  static_cast<float>(v[static_cast<std::size_t>(n)]));

    writeFile(tmp / "short.raw", int16BE({1, 2, 3}));
    writeFile(tmp / "short.mhd",
              "NDims = 3\nDimSize = 3 2 4\nElementType = MET_SHORT\nElementDataFile = short.raw\n");
    expectThrowWith<palp::FormatError>(
        [&] { palp::volume::readMetaImage(tmp / "short.mhd", {}); },
        {(tmp / "short.raw").string() +
         ": expected 48 bytes of voxel data after the header, found 6"});
}

TEST(MetaImage, CompressedLocalDataAnd4D) {
    TempDir tmp;
    std::vector<float> vals = fieldValues(4, 3, 2);
    std::vector<float> second = vals;
    for (float& x : second) x = -x;
    vals.insert(vals.end(), second.begin(), second.end());
    const std::string z = deflateBytes(floatsLE(vals), false);
    writeFile(tmp / "c.mha",
              "ObjectType = Image\nNDims = 4\nBinaryData = True\nBinaryDataByteOrderMSB = False\n"
              "CompressedData = True\nCompressedDataSize = " +
                  std::to_string(z.size()) +
                  "\nTransformMatrix = 1 0 0 0 0 1 0 0 0 0 1 0 0 0 0 1\nOffset = 1 2 3 0\n"
                  "ElementSpacing = 1 1 1 1\nDimSize = 4 3 2 2\nElementType = MET_FLOAT\n"
                  "ElementDataFile = LOCAL\n" +
                  z);
    expectThrowWith<palp::ValueError>(
        [&] { palp::volume::readMetaImage(tmp / "c.mha", {}); },
        {"c.mha: expected a time point to choose one of the 2 time points (0-1), found none"});
    LoadOptions o;
    o.timePoint = 1;
    const SliceStack st = palp::volume::readMetaImage(tmp / "c.mha", o);
    EXPECT_EQ(st.info.timePoint, 1);
    EXPECT_EQ(voxel(st, 3, 2, 1), -static_cast<float>(linearField(3, 2, 1)));
    EXPECT_LT((st.slices[1].position - Eigen::Vector3d(1e-3, 2e-3, 4e-3)).norm(), 1e-15);

    // A 3D file whose compressed stream is cut short.
    const std::string z3 = deflateBytes(floatsLE(fieldValues(4, 3, 2)), false);
    writeFile(tmp / "cut.mha",
              "NDims = 3\nCompressedData = True\nDimSize = 4 3 2\nElementType = MET_FLOAT\n"
              "ElementDataFile = LOCAL\n" +
                  z3.substr(0, z3.size() - 10));
    expectThrowWith<palp::FormatError>([&] { palp::volume::readMetaImage(tmp / "cut.mha", {}); },
                                       {"cut.mha: expected 96 bytes of decompressed voxel data"});
}

TEST(MetaImage, BadHeadersAreRefused) {
    TempDir tmp;
    const fs::path file = tmp / "bad.mha";
    writeFile(file, "NDims = 3\nDimSize = 4 3\nElementType = MET_FLOAT\nElementDataFile = LOCAL\n");
    expectThrowWith<palp::FormatError>(
        [&] { palp::volume::readMetaImage(file, {}); },
        {file.string() + ": line 2: expected 'DimSize' with 3 positive integers, found '4 3'"});
    writeFile(file,
              "NDims = 3\nDimSize = 4 3 2\nElementType = MET_STRING\nElementDataFile = LOCAL\n");
    expectThrowWith<palp::FormatError>(
        [&] { palp::volume::readMetaImage(file, {}); },
        {file.string() + ": line 3: expected 'ElementType' MET_CHAR"});
    writeFile(file,
              "NDims = 3\nDimSize = 4 3 2\nElementType = MET_FLOAT\nElementNumberOfChannels = "
              "3\nElementDataFile = LOCAL\n");
    expectThrowWith<palp::FormatError>([&] { palp::volume::readMetaImage(file, {}); },
                                       {file.string() + ": expected ElementNumberOfChannels 1"});
    writeFile(file,
              "NDims = 3\nDimSize = 100000 100000 100000\nElementType = MET_UCHAR\nElementDataFile "
              "= LOCAL\n");
    expectThrowWith<palp::ValueError>(
        [&] { palp::volume::readMetaImage(file, {}); },
        {file.string() + ": expected at most", "100000 x 100000 x 100000 x 1 bytes"});
    writeFile(file, "NDims = 3\nDimSize = 4 3 2\nElementType = MET_FLOAT\n");
    expectThrowWith<palp::FormatError>([&] { palp::volume::readMetaImage(file, {}); },
                                       {file.string() + ": expected an 'ElementDataFile' line"});
}

// ----------------------------------------------------------------------------------------------
// Through the palp tool

TEST(FormatsTool, ConvertRefusesBadNrrdAndLeavesNoOutput) {
    const fs::path tool = palp::test::palpTool();
    ASSERT_TRUE(fs::exists(tool)) << "palp tool not built at " << tool;
    TempDir tmp;
    writeFile(tmp / "huge.nrrd",
              "NRRD0004\ntype: short\ndimension: 3\nsizes: 100000 100000 100000\n"
              "endian: little\nencoding: raw\n\n\x01\x02");
    writeFile(tmp / "s.raw", std::string(100, '\0'));
    writeFile(tmp / "short.nhdr",
              "NRRD0004\ntype: float\ndimension: 3\nsizes: 2 3 5\nendian: little\n"
              "encoding: raw\ndata file: s.raw\n");
    for (const std::string in : {"huge.nrrd", "short.nhdr"}) {
        const fs::path out = tmp / "out.vdb";
        const auto r = palp::test::runCommand(tool.string() + " convert " + (tmp / in).string() +
                                              " -o " + out.string());
        EXPECT_NE(r.exitCode, 0) << r.output;
        const std::string named =
            in == "huge.nrrd" ? (tmp / in).string() : (tmp / "s.raw").string();
        EXPECT_NE(r.output.find("palp: error: " + named + ":"), std::string::npos) << r.output;
        EXPECT_FALSE(fs::exists(out));
        for (const auto& e : fs::directory_iterator(tmp.path())) {
            EXPECT_EQ(e.path().filename().string().find("out.vdb"), std::string::npos) << e.path();
        }
    }
    // And a good file converts.
    writeFile(tmp / "ok.nrrd",
              "NRRD0004\ntype: float\ndimension: 3\nspace: LPS\nsizes: 4 3 5\n"
              "space directions: (2,0,0) (0,3,0) (0,0,4)\nendian: little\nencoding: raw\n\n" +
                  floatsLE(fieldValues(4, 3, 5)));
    const auto r = palp::test::runCommand(tool.string() + " convert " + (tmp / "ok.nrrd").string() +
                                          " -o " + (tmp / "ok.vdb").string() + " --voxel-size 1");
    EXPECT_EQ(r.exitCode, 0) << r.output;
    EXPECT_TRUE(fs::exists(tmp / "ok.vdb"));
}

}  // namespace
