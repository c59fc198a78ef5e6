#include "palp/volume/load.h"

#include <openvdb/io/File.h>

#include <new>
#include <stdexcept>

#include "lazy_stack.h"
#include "palp/base/atomic_file.h"
#include "palp/base/bounds.h"
#include "palp/base/error.h"
#include "palp/base/parallel.h"
#include "palp/base/validate.h"
#include "resample/resample_detail.h"
#include "vdb/vdb_errors.h"
#include "vdb/vdb_read.h"
#include "vdb/vdb_write.h"

namespace palp::volume {

namespace fs = std::filesystem;

namespace {

/// A stored grid palp can use: a linear transform with cubic voxels, or (native spacing) an
/// axis-aligned scale with a different edge per axis, each edge a voxel spacing
/// (bounds::kSpacing), and finite values inside bounds::kVolumeValue (the background and every
/// active value), so that nothing the file holds reaches the mesher or the kernels unchecked.
/// @throw FormatError naming @p name.
void checkStoredGrid(const std::string& name, const openvdb::FloatGrid& grid) try {
    const openvdb::math::Transform& xform = grid.transform();
    const openvdb::Vec3d voxel = xform.voxelSize();
    const bool cubic = voxel[0] == voxel[1] && voxel[1] == voxel[2];
    bool axisAligned = xform.isLinear();
    if (axisAligned) {
        const openvdb::Mat4d m = xform.baseMap()->getAffineMap()->getMat4();
        for (int r = 0; r < 3; ++r)
            for (int c = 0; c < 3; ++c) axisAligned &= r == c || m(r, c) == 0.0;
    }
    if (!xform.isLinear() || (!cubic && !axisAligned)) {
        throwExpected(name + ": grid transform",
                      "a linear transform with cubic voxels, or an axis-aligned scale",
                      "voxel (" + formatValue(voxel[0] * 1e3) + " " + formatValue(voxel[1] * 1e3) +
                          " " + formatValue(voxel[2] * 1e3) + ") mm" +
                          (xform.isLinear() ? " (rotated)" : " (not linear)"));
    }
    for (int a = 0; a < 3; ++a)
        requireWithin(name + ": grid voxel size", voxel[a], bounds::kSpacing, {1e3, "mm"});
    requireWithin(name + ": grid background", static_cast<double>(grid.background()),
                  bounds::kVolumeValue);
    const auto refuse = [&](const openvdb::Coord& c, float v) {
        requireWithin(name + ": grid value at (" + std::to_string(c.x()) + ", " +
                          std::to_string(c.y()) + ", " + std::to_string(c.z()) + ")",
                      static_cast<double>(v), bounds::kVolumeValue);
    };
    // Active tiles above the leaves (few), then the leaves in parallel: a branch-free pass over
    // each leaf's active values (NaN fails both comparisons), and the first leaf in tree order
    // with a value out of bounds names its first such voxel.
    auto tiles = grid.cbeginValueOn();
    tiles.setMaxDepth(openvdb::FloatTree::ValueOnCIter::LEAF_DEPTH - 1);
    for (; tiles; ++tiles)
        if (!bounds::kVolumeValue.contains(static_cast<double>(*tiles)))
            refuse(tiles.getCoord(), *tiles);
    std::vector<const openvdb::FloatTree::LeafNodeType*> leaves;
    leaves.reserve(grid.tree().leafCount());
    for (auto it = grid.tree().cbeginLeaf(); it; ++it) leaves.push_back(it.getLeaf());
    constexpr auto lo = static_cast<float>(bounds::kVolumeValue.min);
    constexpr auto hi = static_cast<float>(bounds::kVolumeValue.max);
    static_assert(static_cast<double>(lo) == bounds::kVolumeValue.min &&
                  static_cast<double>(hi) == bounds::kVolumeValue.max);
    std::vector<char> bad(leaves.size(), 0);
    palp::parallelForEach(
        std::size_t{0}, leaves.size(),
        [&](std::size_t i) {
            const auto& leaf = *leaves[i];
            const float* v = leaf.buffer().data();
            if (v == nullptr) return;  // no buffer: every value is the (checked) background
            const auto& mask = leaf.getValueMask();
            bool within = true;
            for (openvdb::Index k = 0; k < leaf.SIZE; ++k)
                within &= (!mask.isOn(k)) | ((v[k] >= lo) & (v[k] <= hi));
            bad[i] = within ? 0 : 1;
        },
        std::size_t{64});
    for (std::size_t i = 0; i < leaves.size(); ++i) {
        if (!bad[i]) continue;
        for (auto it = leaves[i]->cbeginValueOn(); it; ++it)
            if (!bounds::kVolumeValue.contains(static_cast<double>(*it)))
                refuse(it.getCoord(), *it);
    }
} catch (const ValueError& e) {
    throw FormatError(e.what());
}

}  // namespace

Volume load(const std::vector<fs::path>& inputs, const LoadOptions& options) {
    initialize();
    checkResampleOptions(options.resample);
    const std::string what = inputs.empty() ? std::string("load") : inputs.front().string();
    return detail::withVdbErrors<FormatError>(what, "a scan OpenVDB can grid", [&] {
        if (inputs.size() == 1) detail::requireExists(inputs.front());
        if (std::optional<detail::LazySliceStack> lazy = detail::openLazy(inputs, options))
            return detail::resampleLazy(*lazy, options.resample);
        // A stored grid has no slices: it is re-gridded as a volume, with the same options.
        if (inputs.size() == 1 && detectFormat(inputs.front()) == Format::Vdb)
            return resample(loadVdb(inputs.front()), options.resample);
        // An unknown format or several non-DICOM inputs: readStack() says what is wrong.
        return resample(readStack(inputs, options), options.resample);
    });
}

Volume loadVdb(const fs::path& path) {
    initialize();
    openvdb::GridPtrVecPtr grids;
    try {
        grids = detail::readGridsMapped(path);
    } catch (const openvdb::Exception& e) {
        throw IoError(path.string() +
                      ": expected a readable OpenVDB file, found an error: " + e.what());
    } catch (const std::bad_alloc&) {
        // A (damaged) file whose sizes drive an allocation larger than memory.
        throw FormatError(path.string() +
                          ": expected a readable OpenVDB file, found sizes that cannot be "
                          "allocated (out of memory)");
    } catch (const std::length_error& e) {
        throw FormatError(path.string() +
                          ": expected a readable OpenVDB file, found impossible sizes (" +
                          e.what() + ")");
    }
    openvdb::FloatGrid::Ptr chosen;
    for (const auto& g : *grids) {
        if (auto fg = openvdb::gridPtrCast<openvdb::FloatGrid>(g)) {
            if (fg->getName() == kScanGridName) {
                chosen = fg;
                break;
            }
            if (!chosen) chosen = fg;
        }
    }
    if (!chosen) {
        throw FormatError(path.string() + ": expected a float grid named 'scan', found " +
                          std::to_string(grids->size()) + " grids and none of type float");
    }
    checkStoredGrid(path.string(), *chosen);
    return Volume{chosen, readInfo(*chosen)};
}

void save(const Volume& volume, const fs::path& path, const SaveOptions& options) {
    initialize();
    if (!volume.grid) throwExpected(path.string(), "a volume with a grid", "none");
    AtomicFile out(path, "volume");
    // A grid sharing the caller's tree and transform, with metadata and name of its own,
    // carries the file's name and metadata, so the caller's grid is left as it was; its leaves
    // are compressed in parallel (the bytes OpenVDB's serial writer would write).
    const openvdb::FloatGrid::Ptr grid = detail::parallelWritingGrid(*volume.grid);
    writeInfo(volume.info, *grid);
    grid->setName(kScanGridName);
    try {
        openvdb::io::File file(out.tempPath().string());
        std::uint32_t flags = openvdb::io::COMPRESS_ACTIVE_MASK;
        if (options.compression == Compression::Blosc &&
            openvdb::io::Archive::hasBloscCompression()) {
            flags |= openvdb::io::COMPRESS_BLOSC;
        } else if (options.compression != Compression::ActiveMask) {
            flags |= openvdb::io::COMPRESS_ZIP;
        }
        file.setCompression(flags);
        openvdb::MetaMap fileMeta;
        fileMeta.insertMeta("creator", openvdb::StringMetadata("palp"));
        file.write({grid}, fileMeta);
        file.close();
    } catch (const std::exception& e) {
        throw IoError(path.string() +
                      ": expected a writable location, found an error: " + e.what());
    }
    out.commit();
}

}  // namespace palp::volume

namespace {

palp::volume::ConvertSummary loadAndSave(const std::vector<std::filesystem::path>& inputs,
                                         const std::filesystem::path& output,
                                         const palp::volume::LoadOptions& options,
                                         const palp::volume::SaveOptions& saveOptions) {
    using namespace palp::volume;
    const Volume v = load(inputs, options);
    save(v, output, saveOptions);
    return ConvertSummary{v.info, v.grid->activeVoxelCount(), v.worldBounds(), v.voxelSizes(),
                          v.grid->background()};
}

}  // namespace

/// convert()'s way through load() and save(), for palp_volume_core (kLoadAndSaveEntry).
extern "C" __attribute__((visibility("default"))) palp::volume::ConvertFn
palp_volume_load_and_save() {
    return &loadAndSave;
}
