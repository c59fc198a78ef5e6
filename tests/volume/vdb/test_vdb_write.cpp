// save() compresses leaves in parallel, convert() writes packed leaves without a grid: each
// file must be the one OpenVDB's serial writer makes.
#include <gtest/gtest.h>
#include <openvdb/io/File.h>

#include <filesystem>
#include <fstream>
#include <iterator>
#include <random>
#include <vector>

#include "palp/base/parallel.h"
#include "palp/volume/load.h"
#include "palp/volume/resample.h"
#include "resample/grid_copy.h"
#include "test_support.h"
#include "tilted_series.h"
#include "vdb/vdb_packed.h"

namespace {

namespace fs = std::filesystem;
using palp::volume::Compression;

std::vector<char> bytesOf(const fs::path& p) {
    std::ifstream in(p, std::ios::binary);
    return {std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
}

/// Expects files @p a and @p b to have the same bytes but for the UUID in the header (36
/// characters within the first 64 bytes).
void expectSameButUuid(const fs::path& a, const fs::path& b) {
    const std::vector<char> x = bytesOf(a), y = bytesOf(b);
    ASSERT_EQ(x.size(), y.size());
    std::size_t first = x.size(), last = 0;
    for (std::size_t i = 0; i < x.size(); ++i) {
        if (x[i] != y[i]) {
            first = std::min(first, i);
            last = i;
        }
    }
    if (first < x.size()) {
        EXPECT_LT(last, 64u) << "bytes differ past the header, from byte " << first;
        EXPECT_LT(last - first, 36u);
    }
}

TEST(VdbWrite, ParallelSaveWritesTheSerialWritersBytes) {
    palp::volume::initialize();
    // ~1,100 leaves with values, a background and partly filled leaves at the head's edge.
    palp::volume::ResampleOptions opt;
    opt.voxelSize = 0.6e-3;
    const palp::volume::Volume v =
        palp::volume::resample(palp::test::tiltedSeries(96, 80, 40, 0.9e-3, 1.1e-3, 14.0), opt);
    ASSERT_GT(v.grid->tree().leafCount(), 1000u);
    // The resampler leaves every inactive value at the background, and save() writes such
    // leaves itself; a copy whose inactive values are not all the background in some leaves
    // (-background, one other value, two, three) takes OpenVDB's own writer for those.
    palp::volume::Volume odd = v;
    odd.grid = v.grid->deepCopy();
    {
        std::vector<openvdb::FloatTree::LeafNodeType*> leaves;
        odd.grid->tree().getNodes(leaves);
        const float bg = odd.grid->background();
        std::size_t changed = 0;
        for (std::size_t i = 0; i < leaves.size() && changed < 4; i += 97) {
            auto& leaf = *leaves[i];
            std::vector<openvdb::Index> off;
            for (auto it = leaf.cbeginValueOff(); it; ++it) off.push_back(it.pos());
            if (off.size() < 3) continue;
            const float others[4][3] = {
                {-bg, -bg, -bg}, {7.5f, 7.5f, 7.5f}, {7.5f, -2.0f, 7.5f}, {1.0f, 2.0f, 3.0f}};
            for (std::size_t k = 0; k < 3; ++k) leaf.setValueOnly(off[k], others[changed][k]);
            ++changed;
        }
        ASSERT_EQ(changed, 4u);
    }
    const palp::test::TempDir dir;
    for (const palp::volume::Volume* vol : {&v, static_cast<const palp::volume::Volume*>(&odd)}) {
        const std::vector<std::pair<Compression, std::uint32_t>> modes = {
            {Compression::ActiveMask, openvdb::io::COMPRESS_ACTIVE_MASK},
            {Compression::Blosc, openvdb::io::COMPRESS_ACTIVE_MASK | openvdb::io::COMPRESS_BLOSC},
            {Compression::Zip, openvdb::io::COMPRESS_ACTIVE_MASK | openvdb::io::COMPRESS_ZIP}};
        for (const auto& [mode, flags] : modes) {
            SCOPED_TRACE(flags);
            const fs::path parallel = dir.path() / "parallel.vdb";
            const fs::path serial = dir.path() / "serial.vdb";
            palp::volume::SaveOptions so;
            so.compression = mode;
            palp::volume::save(*vol, parallel, so);
            // What save() writes, through OpenVDB's own serial writer.
            auto grid = palp::volume::detail::gridWithTree(*vol->grid, vol->grid->treePtr());
            palp::volume::writeInfo(vol->info, *grid);
            grid->setName(palp::volume::kScanGridName);
            openvdb::io::File file(serial.string());
            file.setCompression(flags);
            openvdb::MetaMap meta;
            meta.insertMeta("creator", openvdb::StringMetadata("palp"));
            file.write({grid}, meta);
            file.close();
            // Only the file's UUID (36 characters in the header) may differ.
            expectSameButUuid(parallel, serial);
            // And it reads back as the same grid.
            const palp::volume::Volume back = palp::volume::loadVdb(parallel);
            EXPECT_EQ(back.grid->activeVoxelCount(), vol->grid->activeVoxelCount());
            EXPECT_EQ(back.grid->tree().leafCount(), vol->grid->tree().leafCount());
        }
    }
}

/// Writes @p grid as save() would have OpenVDB write it (active-mask compression, the file's
/// creator), through OpenVDB's own serial writer.
void writeWithOpenVdb(const openvdb::FloatGrid::Ptr& grid, const fs::path& path) {
    openvdb::io::File file(path.string());
    file.setCompression(openvdb::io::COMPRESS_ACTIVE_MASK);
    openvdb::MetaMap meta;
    meta.insertMeta("creator", openvdb::StringMetadata("palp"));
    file.write({grid}, meta);
    file.close();
}

TEST(VdbWrite, PackedLeavesWriteTheSerialWritersBytes) {
    palp::volume::initialize();
    using LeafT = openvdb::FloatTree::LeafNodeType;
    // Leaves in several top nodes (4096 voxels a side) and lower nodes (128), at negative
    // coordinates too, each with its own random mask: one voxel, a full leaf, and the rest;
    // every inactive value the background, as the resampler leaves them.
    const float background = -1000.0f;
    std::vector<openvdb::Coord> origins = {
        {0, 0, 0},    {8, 0, 0},       {0, 8, 0},       {0, 0, 8},     {120, 0, 0},
        {128, 0, 0},  {0, 128, 0},     {0, 0, 128},     {-8, 0, 0},    {0, -8, -4096},
        {4096, 0, 0}, {4088, 4096, 8}, {-4104, 16, 24}, {0, 4096, -8}, {4096, -128, 16}};
    std::mt19937 rng(7);
    std::uniform_int_distribution<int> pick(-300, 300);
    for (int i = 0; i < 400; ++i) origins.emplace_back(8 * pick(rng), 8 * pick(rng), 8 * pick(rng));
    std::sort(origins.begin(), origins.end());
    origins.erase(std::unique(origins.begin(), origins.end()), origins.end());
    std::vector<std::vector<float>> values(origins.size(), std::vector<float>(LeafT::SIZE));
    std::vector<LeafT::NodeMaskType> masks(origins.size());
    std::uniform_real_distribution<float> value(-900.0f, 3000.0f);
    std::uniform_int_distribution<int> fill(0, 99);
    for (std::size_t i = 0; i < origins.size(); ++i) {
        const int percent = i == 0 ? -1 : i == 1 ? 100 : fill(rng);
        for (openvdb::Index k = 0; k < LeafT::SIZE; ++k) {
            const bool on = i == 0 ? k == 200 : fill(rng) < percent;
            values[i][k] = on ? value(rng) : background;
            if (on) masks[i].setOn(k);
        }
    }
    palp::volume::VolumeInfo info;
    info.modality = "CT";
    info.valueUnits = "HU";
    info.originalDims = {512, 512, 300};
    info.originalSpacing = {0.48e-3, 0.48e-3, 0.6e-3};
    info.phaseEncodingPolarityGE = "Flipped";
    info.valuesBelowThreshold = 12345;
    const palp::test::TempDir dir;
    const fs::path mine = dir / "packed.vdb", theirs = dir / "openvdb.vdb";
    // The first n leaves: none, one, 60 (the delayed-load masks stored raw, and padded for
    // Blosc) and all; on a uniform scale with a translation (the resampler's cubic voxels) and
    // on a per-axis scale (native spacing).
    struct Lattice {
        Eigen::Vector3d step, lo;
    };
    for (const Lattice& lat : {Lattice{Eigen::Vector3d::Constant(0.5e-3), {0.01, -0.02, 0.03}},
                               Lattice{{0.48e-3, 0.5e-3, 1.25e-3}, {-0.1, 0.2, -0.3}}}) {
        for (const std::size_t n :
             {std::size_t{0}, std::size_t{1}, std::size_t{60}, origins.size()}) {
            SCOPED_TRACE("leaves " + std::to_string(n) + ", step x " +
                         std::to_string(lat.step.x()) + " y " + std::to_string(lat.step.y()));
            // OpenVDB's grid of those leaves, as resample() makes it.
            auto grid = openvdb::FloatGrid::create(background);
            grid->setName(palp::volume::kScanGridName);
            const openvdb::Vec3d lo(lat.lo.data()), step(lat.step.data());
            if (lat.step.x() == lat.step.y()) {
                grid->setTransform(openvdb::math::Transform::createLinearTransform(step.x()));
                grid->transform().postTranslate(lo);
            } else {
                grid->setTransform(std::make_shared<openvdb::math::Transform>(
                    std::make_shared<openvdb::math::ScaleTranslateMap>(step, lo)));
            }
            palp::volume::writeInfo(info, *grid);
            for (std::size_t i = 0; i < n; ++i) {
                auto* leaf = new LeafT(origins[i], background);
                for (openvdb::Index k = 0; k < LeafT::SIZE; ++k)
                    leaf->setValueOnly(k, values[i][k]);
                leaf->setValueMask(masks[i]);
                grid->tree().addLeaf(leaf);
            }
            // Packed from several threads, in no particular order (palp::parallelForEach: the
            // fork and join ThreadSanitizer sees).
            palp::volume::detail::PackedLeaves packed;
            palp::parallelForEach(
                std::size_t{0}, n,
                [&](std::size_t j) {
                    const std::size_t i = n - 1 - j;
                    packed.add(origins[i], masks[i], values[i].data());
                },
                std::size_t{8});
            const palp::volume::detail::PackedGrid header{info, lat.step, lat.lo, background};
            const palp::volume::detail::PackedStats stats =
                palp::volume::detail::writePackedVdb(header, packed, mine);
            writeWithOpenVdb(grid, theirs);
            expectSameButUuid(mine, theirs);
            EXPECT_EQ(stats.activeVoxels, grid->activeVoxelCount());
            EXPECT_EQ(stats.box, grid->evalActiveVoxelBoundingBox());
            EXPECT_EQ(stats.box.empty(), n == 0);
        }
    }
}

/// convert() of @p inputs writes what save(load()) writes; returns the convert() summary.
palp::volume::ConvertSummary expectConvertIsSaveOfLoad(const std::vector<fs::path>& inputs,
                                                       const palp::volume::LoadOptions& opt) {
    const palp::test::TempDir dir;
    const fs::path converted = dir / "convert.vdb", saved = dir / "save.vdb";
    const palp::volume::ConvertSummary s = palp::volume::convert(inputs, converted, opt);
    const palp::volume::Volume v = palp::volume::load(inputs, opt);
    palp::volume::save(v, saved);
    expectSameButUuid(converted, saved);
    EXPECT_EQ(s.activeVoxels, v.grid->activeVoxelCount());
    const openvdb::BBoxd a = s.worldBounds, b = v.worldBounds();
    EXPECT_EQ(a.min(), b.min());
    EXPECT_EQ(a.max(), b.max());
    EXPECT_EQ(s.voxelSizes, v.voxelSizes());
    EXPECT_EQ(s.background, v.grid->background());
    EXPECT_EQ(s.info.valuesBelowThreshold, v.info.valuesBelowThreshold);
    return s;
}

TEST(VdbWrite, ConvertWritesWhatSaveOfLoadWrites) {
    palp::volume::initialize();
    const palp::test::TempDir tmp;
    // A generated NRRD (oblique axes: the per-block kernel), at the finest spacing and coarser.
    std::vector<float> field;
    for (int k = 0; k < 21; ++k)
        for (int j = 0; j < 27; ++j)
            for (int i = 0; i < 31; ++i)
                field.push_back(static_cast<float>((i * 7 + j * 3 + k * 11) % 400 - 40));
    palp::test::writeFile(tmp / "a.nrrd",
                          "NRRD0004\ndimension: 3\nsizes: 31 27 21\ntype: float\n"
                          "space: left-posterior-superior\nspace origin: (3,-4,5)\n"
                          "space directions: (1.2,0,0) (0,0.8,0.1) (0,-0.2,1.4)\n"
                          "endian: little\nencoding: raw\n\n" +
                              palp::test::floatsLE(field));
    palp::volume::LoadOptions opt;
    expectConvertIsSaveOfLoad({tmp / "a.nrrd"}, opt);
    opt.resample.voxelSize = 1.7e-3;
    opt.resample.backgroundThreshold = 100.0f;
    expectConvertIsSaveOfLoad({tmp / "a.nrrd"}, opt);
    // Everything below the threshold: a file without leaves.
    opt.resample.backgroundThreshold = 1000.0f;
    EXPECT_EQ(expectConvertIsSaveOfLoad({tmp / "a.nrrd"}, opt).activeVoxels, 0u);
}

TEST(VdbWrite, ConvertOfRealScansWritesWhatSaveOfLoadWrites) {
    PALP_REQUIRE_DATA(head, "ct-ge-head-tilt");
    PALP_REQUIRE_DATA(mr, "nifti-mr");
    PALP_REQUIRE_DATA(formats, "mr-one-volume-many-formats");
    palp::volume::initialize();
    // The tilted head CT by rows of blocks, at 1 mm and cropped to a box at 0.5 mm.
    palp::volume::LoadOptions opt;
    opt.resample.voxelSize = 1e-3;
    expectConvertIsSaveOfLoad({head}, opt);
    opt.resample.voxelSize = 0.5e-3;
    opt.resample.crop = palp::volume::WorldBox{{-0.05, -0.04, -0.03}, {0.04, 0.05, 0.06}};
    expectConvertIsSaveOfLoad({head}, opt);
    // A big-endian NIfTI MR, its default threshold and spacing.
    expectConvertIsSaveOfLoad({mr / "anatomical.nii"}, {});
    // Native spacing: the MetaImage MR's 3.437 x 3.438 x 3.8 mm voxels, a per-axis scale whose
    // stored value OpenVDB's transform rounds (storedMap()), and the NIfTI's cubic 2 mm ones.
    palp::volume::LoadOptions native;
    native.resample.nativeSpacing = true;
    const palp::volume::ConvertSummary s = expectConvertIsSaveOfLoad({formats / "mha.mha"}, native);
    EXPECT_FALSE(s.hasCubicVoxels());
    EXPECT_TRUE(expectConvertIsSaveOfLoad({mr / "anatomical.nii"}, native).hasCubicVoxels());
}

}  // namespace
