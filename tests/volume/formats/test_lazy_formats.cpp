// load() of a NIfTI, NRRD or MetaImage volume decodes it a slice at a time as the resampler
// reaches it (raw_slices.h): the grid is the one resample(readStack()) gives of the whole decoded
// volume, and the peak memory does not hold the volume as float beside the grid.
#include <gtest/gtest.h>
#include <malloc.h>
#include <nifti1_io.h>

#include <cstdint>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <string>
#include <vector>

#include "formats/raw_slices.h"
#include "memory_use.h"
#include "palp/base/error.h"
#include "palp/volume/load.h"
#include "test_support.h"

namespace {

namespace fs = std::filesystem;
using palp::test::deflateBytes;
using palp::test::TempDir;
using palp::test::writeFile;
using palp::volume::LoadOptions;
using palp::volume::Volume;

/// Both grids hold the same active voxels with the same values, the same background and
/// transform.
void expectSameGrid(const Volume& a, const Volume& b) {
    ASSERT_TRUE(a.grid && b.grid);
    EXPECT_TRUE(a.grid->transform() == b.grid->transform());
    EXPECT_EQ(a.grid->background(), b.grid->background());
    ASSERT_EQ(a.grid->activeVoxelCount(), b.grid->activeVoxelCount());
    ASSERT_GT(a.grid->activeVoxelCount(), 0u);
    auto acc = b.grid->getConstAccessor();
    std::size_t differ = 0;
    for (auto it = a.grid->cbeginValueOn(); it; ++it) {
        float v = 0;
        if (!acc.probeValue(it.getCoord(), v) || v != *it) ++differ;
    }
    EXPECT_EQ(differ, 0u);
}

/// load() (a slice at a time) against resample() of readStack() (the whole volume decoded).
void expectLazyEqualsWhole(const fs::path& file, const LoadOptions& opt = {}) {
    SCOPED_TRACE(file.string());
    const Volume lazy = palp::volume::load({file}, opt);
    const Volume whole = palp::volume::resample(palp::volume::readStack({file}, opt), opt.resample);
    expectSameGrid(lazy, whole);
    EXPECT_EQ(lazy.info.sourceFormat, whole.info.sourceFormat);
    EXPECT_EQ(lazy.info.originalDims, whole.info.originalDims);
    EXPECT_EQ(lazy.info.timePoint, whole.info.timePoint);
}

/// An int16 NIfTI-1 (.nii, or .nii.gz when @p name ends so) of nx x ny x nz x nt voxels, value
/// (i, j, k, t) = f(i, j, k, t), scaled by scl_slope 0.5 and scl_inter 10, with an oblique sform.
template <typename F>
fs::path niftiInt16(const fs::path& dir, const std::string& name, int nx, int ny, int nz, int nt,
                    F f) {
    nifti_1_header h{};
    h.sizeof_hdr = 348;
    h.dim[0] = nt > 1 ? 4 : 3;
    h.dim[1] = static_cast<short>(nx);
    h.dim[2] = static_cast<short>(ny);
    h.dim[3] = static_cast<short>(nz);
    h.dim[4] = static_cast<short>(nt);
    for (int d = 5; d < 8; ++d) h.dim[d] = 1;
    h.datatype = DT_INT16;
    h.bitpix = 16;
    h.pixdim[0] = 1;
    h.pixdim[1] = 0.9f;
    h.pixdim[2] = 1.1f;
    h.pixdim[3] = 1.5f;
    h.pixdim[4] = 1;
    h.vox_offset = 352;
    h.scl_slope = 0.5f;
    h.scl_inter = 10;
    h.xyzt_units = NIFTI_UNITS_MM;
    h.sform_code = 1;
    const float srow[3][4] = {{0.9f * 0.96f, 0, 1.5f * 0.28f, -20},
                              {0, 1.1f, 0, 15},
                              {-0.9f * 0.28f, 0, 1.5f * 0.96f, 40}};
    std::memcpy(h.srow_x, srow[0], sizeof h.srow_x);
    std::memcpy(h.srow_y, srow[1], sizeof h.srow_y);
    std::memcpy(h.srow_z, srow[2], sizeof h.srow_z);
    std::memcpy(h.magic, "n+1", 4);
    std::string bytes(352, '\0');
    std::memcpy(bytes.data(), &h, sizeof h);
    bytes.reserve(bytes.size() +
                  2 * static_cast<std::size_t>(nx * ny) * static_cast<std::size_t>(nz * nt));
    for (int t = 0; t < nt; ++t)
        for (int k = 0; k < nz; ++k)
            for (int j = 0; j < ny; ++j)
                for (int i = 0; i < nx; ++i) {
                    const auto v = static_cast<std::int16_t>(f(i, j, k, t));
                    char two[2];
                    std::memcpy(two, &v, 2);
                    bytes.append(two, 2);
                }
    const fs::path file = dir / name;
    const bool gz = name.size() > 3 && name.compare(name.size() - 3, 3, ".gz") == 0;
    writeFile(file, gz ? deflateBytes(bytes, true, 1) : bytes);
    return file;
}

int field(int i, int j, int k, int t) { return (i * 7 + j * 3 + k * 11 + t * 50) % 400 - 40; }

/// @p values (i fastest) as little-endian float32 bytes.
std::string floatField(int nx, int ny, int nz, int nt) {
    std::vector<float> v;
    for (int t = 0; t < nt; ++t)
        for (int k = 0; k < nz; ++k)
            for (int j = 0; j < ny; ++j)
                for (int i = 0; i < nx; ++i) v.push_back(static_cast<float>(field(i, j, k, t)));
    return palp::test::floatsLE(v);
}

TEST(LazyFormats, NiftiGivesTheGridOfTheWholeVolume) {
    TempDir tmp;
    expectLazyEqualsWhole(niftiInt16(tmp.path(), "a.nii", 23, 19, 17, 1, field));
    expectLazyEqualsWhole(niftiInt16(tmp.path(), "a.nii.gz", 23, 19, 17, 1, field));
    // The second time point of a 4D file, stored and gzip-compressed.
    LoadOptions second;
    second.timePoint = 1;
    expectLazyEqualsWhole(niftiInt16(tmp.path(), "b.nii", 23, 19, 17, 3, field), second);
    expectLazyEqualsWhole(niftiInt16(tmp.path(), "b.nii.gz", 23, 19, 17, 3, field), second);
    // Its values are the file's: slope 0.5, intercept 10 (a voxel at the lattice's corner).
    const auto stack = palp::volume::readStack({tmp / "b.nii"}, second);
    ASSERT_EQ(stack.slices.size(), 17u);
    EXPECT_EQ(stack.slices[4].values[5 * 23 + 6],
              0.5f * static_cast<float>(field(6, 5, 4, 1)) + 10);
}

TEST(LazyFormats, RealNiftiFilesGiveTheGridOfTheWholeVolume) {
    PALP_REQUIRE_DATA(dir, "nifti-mr");
    expectLazyEqualsWhole(dir / "anatomical.nii");  // big-endian
    LoadOptions second;
    second.timePoint = 1;
    expectLazyEqualsWhole(dir / "example4d.nii.gz", second);
}

TEST(LazyFormats, NrrdAndMetaImageGiveTheGridOfTheWholeVolume) {
    TempDir tmp;
    const std::string data = floatField(13, 11, 9, 2);
    const std::string common =
        "type: float\nspace: left-posterior-superior\nspace origin: (3,-4,5)\nendian: little\n";
    const std::string dirs = "(1.2,0,0) (0,0.8,0.1) (0,-0.2,1.4)";
    // Raw and gzip, a time axis last (decoded a slice at a time); a time axis first (read whole).
    writeFile(tmp / "raw.nrrd", "NRRD0004\ndimension: 4\nsizes: 13 11 9 2\n" + common +
                                    "space directions: " + dirs + " none\nencoding: raw\n\n" +
                                    data);
    writeFile(tmp / "gz.nrrd", "NRRD0004\ndimension: 3\nsizes: 13 11 9\n" + common +
                                   "space directions: " + dirs + "\nencoding: gzip\n\n" +
                                   deflateBytes(data.substr(0, data.size() / 2), true, 1));
    writeFile(tmp / "first.nrrd", "NRRD0004\ndimension: 4\nsizes: 2 13 11 9\n" + common +
                                      "space directions: none " + dirs + "\nencoding: raw\n\n" +
                                      data);
    LoadOptions second;
    second.timePoint = 1;
    expectLazyEqualsWhole(tmp / "raw.nrrd", second);
    expectLazyEqualsWhole(tmp / "gz.nrrd");
    expectLazyEqualsWhole(tmp / "first.nrrd", second);
    const std::string mhaHeader =
        "ObjectType = Image\nNDims = 3\nDimSize = 13 11 9\nElementType = MET_FLOAT\n"
        "ElementSpacing = 1.2 0.8 1.4\nOffset = 3 -4 5\nTransformMatrix = 1 0 0 0 1 0 0 0 1\n"
        "BinaryData = True\nBinaryDataByteOrderMSB = False\n";
    const std::string one = data.substr(0, data.size() / 2);
    writeFile(tmp / "raw.mha", mhaHeader + "ElementDataFile = LOCAL\n" + one);
    const std::string z = deflateBytes(one, true, 1);
    writeFile(tmp / "z.mha", mhaHeader + "CompressedData = True\nCompressedDataSize = " +
                                 std::to_string(z.size()) + "\nElementDataFile = LOCAL\n" + z);
    expectLazyEqualsWhole(tmp / "raw.mha");
    expectLazyEqualsWhole(tmp / "z.mha");
}

TEST(LazyFormats, SlicesDecompressedFromTheStreamsIndexEqualTheKeptBytes) {
    // load() indexes compressed volumes of 32 MiB or more (the peak-memory test below); here the
    // threshold is lowered so small streams take that path, in parallel (decodeAll), under the
    // sanitizers too. The second volume of a two-volume stream, with bytes before and after it.
    TempDir tmp;
    const std::int64_t nx = 61, ny = 47, nz = 29;
    const std::size_t volume = static_cast<std::size_t>(nx * ny * nz) * 2;
    std::string data(2 * volume + 999, '\0');
    std::uint32_t x = 7;
    for (std::size_t i = 0; i < data.size(); i += 2) {
        x = x * 1664525u + 1013904223u;
        const auto v = static_cast<std::int16_t>((i / 2) % 3000 - 1000 + ((x >> 24) & 15));
        std::memcpy(&data[i], &v, 2);
    }
    const std::string header(348, 'h');
    writeFile(tmp / "v.gz", header + deflateBytes(data, true, 1));
    palp::volume::detail::RawVolume raw;
    raw.file = tmp / "v.gz";
    raw.item = raw.file.string();
    raw.compressed = true;
    raw.offset = header.size();
    raw.streamBytes = data.size();
    raw.volumeAt = volume;
    raw.type = palp::volume::ElementType::Int16;
    raw.dims = {nx, ny, nz};
    raw.rescale = true;
    raw.slope = 0.5;
    raw.intercept = -3;
    const Eigen::Matrix3d axes = Eigen::Vector3d(1e-3, 1.1e-3, 2e-3).asDiagonal();
    const Eigen::Vector3d origin(0.01, -0.02, 0.03);
    const auto decode = [&](std::uint64_t indexFrom) {
        raw.indexFromBytes = indexFrom;
        return palp::volume::detail::decodeAll(
            palp::volume::detail::openRawVolume(raw, axes, origin));
    };
    const palp::volume::SliceStack kept = decode(UINT64_MAX), indexed = decode(0);
    ASSERT_EQ(indexed.slices.size(), static_cast<std::size_t>(nz));
    for (std::size_t k = 0; k < indexed.slices.size(); ++k) {
        ASSERT_EQ(indexed.slices[k].values, kept.slices[k].values) << "slice " << k;
        // And the file's own values: slice k of the second volume.
        const std::size_t at = volume + k * static_cast<std::size_t>(nx * ny) * 2 + 2 * 5;
        std::int16_t v;
        std::memcpy(&v, &data[at], 2);
        EXPECT_EQ(indexed.slices[k].values[5], 0.5f * static_cast<float>(v) - 3.0f);
    }
}

TEST(LazyFormats, ADamagedStreamOrAShortFileIsRefusedByLoad) {
    TempDir tmp;
    const fs::path good = niftiInt16(tmp.path(), "a.nii.gz", 23, 19, 17, 1, field);
    std::string bytes;
    {
        std::ifstream in(good, std::ios::binary);
        bytes.assign(std::istreambuf_iterator<char>(in), {});
    }
    writeFile(tmp / "cut.nii.gz", bytes.substr(0, bytes.size() / 2));
    palp::test::expectThrowWith<palp::FormatError>(
        [&] { (void)palp::volume::load({tmp / "cut.nii.gz"}); }, {"cut.nii.gz", "truncated"});
    const fs::path raw = niftiInt16(tmp.path(), "b.nii", 23, 19, 17, 1, field);
    std::filesystem::resize_file(raw, std::filesystem::file_size(raw) - 100);
    palp::test::expectThrowWith<palp::FormatError>([&] { (void)palp::volume::load({raw}); },
                                                   {"b.nii", "bytes of voxel data"});
}

TEST(LazyFormats, PeakMemoryDoesNotHoldTheVolumeAsFloat) {
    // A 256 x 256 x 256 int16 volume (33.6 MB stored, 67 MB as float) whose active voxels are a
    // 64^3 cube: a small grid. Reading it whole held the stored bytes, the volume as float and
    // its slices as float (> 160 MB); load() holds a band of slices beside the grid: read from the
    // raw file, or decompressed again from the gzip stream's access points (~4 MB of them), its
    // stored bytes not kept. Both give the same grid.
#if defined(__SANITIZE_ADDRESS__) || defined(__SANITIZE_THREAD__)
    GTEST_SKIP() << "the sanitizer's shadow memory and quarantine change the resident set";
#endif
    TempDir tmp;
    const auto cube = [](int i, int j, int k, int) {
        const bool in = i >= 96 && i < 160 && j >= 96 && j < 160 && k >= 96 && k < 160;
        return in ? 200 + (i + j + k) % 50 : -100;
    };
    const double stored = 256.0 * 256 * 256 * 2, asFloat = 2 * stored;
    openvdb::FloatGrid::Ptr first;
    for (const char* name : {"big.nii", "big.nii.gz"}) {
        SCOPED_TRACE(name);
        const fs::path file = niftiInt16(tmp.path(), name, 256, 256, 256, 1, cube);
        malloc_trim(0);
        std::ofstream("/proc/self/clear_refs") << "5";  // resets VmHWM to the current RSS
        const auto [before, peak0] = palp::test::rssAndPeak();
        if (std::abs(peak0 - before) > 4e6) GTEST_SKIP() << "this kernel cannot reset VmHWM";
        const Volume v = palp::volume::load({file});
        const auto [after, peak] = palp::test::rssAndPeak();
        const double grid = static_cast<double>(v.grid->memUsage());
        const double held = peak - before;
        const bool gz = std::string(name).ends_with(".gz");
        std::printf(
            "%s: peak %.1f MB above before, grid %.1f MB, stored %.1f MB, as float %.1f MB\n", name,
            held / 1e6, grid / 1e6, stored / 1e6, asFloat / 1e6);
        EXPECT_LT(grid, 0.2 * asFloat) << "the test must tell a volume held as float";
        EXPECT_LE(held, 1.5 * grid + (gz ? 8e6 : 0.0) + 24e6);
        EXPECT_LT(held, asFloat);
        if (!first) {
            first = v.grid;
        } else {
            EXPECT_EQ(v.grid->activeVoxelCount(), first->activeVoxelCount());
            std::size_t differ = 0;
            for (auto it = first->cbeginValueOn(); it; ++it)
                differ += v.grid->tree().getValue(it.getCoord()) != *it;
            EXPECT_EQ(differ, 0u);
        }
    }
}

}  // namespace
