// save() compresses leaves in parallel: the file must be the one OpenVDB's serial writer makes.
#include <gtest/gtest.h>
#include <openvdb/io/File.h>

#include <filesystem>
#include <fstream>
#include <iterator>
#include <vector>

#include "palp/volume/load.h"
#include "palp/volume/resample.h"
#include "resample/grid_copy.h"
#include "test_support.h"
#include "tilted_series.h"

namespace {

namespace fs = std::filesystem;
using palp::volume::Compression;

std::vector<char> bytesOf(const fs::path& p) {
    std::ifstream in(p, std::ios::binary);
    return {std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
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
            const std::vector<char> a = bytesOf(parallel), b = bytesOf(serial);
            ASSERT_EQ(a.size(), b.size());
            // Only the file's UUID (36 characters in the header) may differ.
            std::size_t first = a.size(), last = 0;
            for (std::size_t i = 0; i < a.size(); ++i) {
                if (a[i] != b[i]) {
                    first = std::min(first, i);
                    last = i;
                }
            }
            if (first < a.size()) {
                EXPECT_LT(last, 64u) << "bytes differ past the header";
                EXPECT_LT(last - first, 36u);
            }
            // And it reads back as the same grid.
            const palp::volume::Volume back = palp::volume::loadVdb(parallel);
            EXPECT_EQ(back.grid->activeVoxelCount(), vol->grid->activeVoxelCount());
            EXPECT_EQ(back.grid->tree().leafCount(), vol->grid->tree().leafCount());
        }
    }
}

}  // namespace
