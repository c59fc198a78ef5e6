#pragma once
/// @file
/// Internal to palp_volume: leaves kept as the file stores them, not as a grid, and the .vdb
/// written from them (palp convert: the grid's values are never held in memory).

#include <openvdb/openvdb.h>
#include <tbb/enumerable_thread_specific.h>

#include <cstddef>
#include <cstdint>
#include <filesystem>
#include <memory>
#include <string>
#include <vector>

namespace palp::volume::detail {

/// The packed leaves' active voxels and their index-space box (empty for none).
struct PackedStats {
    std::uint64_t activeVoxels = 0;
    openvdb::CoordBBox box;
};

/// Leaves packed as LeafNode::writeBuffers writes them in a mask-compressed file (value mask,
/// metadata byte, active values: packLeafBuffers), each leaf's bytes appended by the thread
/// that filled it to memory of its own. A leaf whose every inactive value is the background
/// is all that may be added (the resampler's leaves are).
/// @par Threading  add() from any number of threads at once; the rest from one.
class PackedLeaves {
  public:
    PackedLeaves() = default;
    PackedLeaves(const PackedLeaves&) = delete;
    PackedLeaves& operator=(const PackedLeaves&) = delete;

    /// Packs the leaf at @p origin (a multiple of 8 on each axis, each origin once) with value
    /// mask @p mask and 512 values @p values.
    void add(const openvdb::Coord& origin, const openvdb::util::NodeMask<3>& mask,
             const float* values);

    /// One packed leaf: where its bytes are and how many, and its place in a tree's leaf order
    /// (orderHigh, then orderLow: see treeOrder in vdb_packed.cpp).
    struct Leaf {
        openvdb::Coord origin;
        const char* bytes;
        std::size_t size;
        std::uint64_t orderHigh, orderLow;
    };
    /// Every leaf added, in the order a FloatTree's leaf iterator would visit them (the order
    /// of the buffers in the file). Not thread-safe against add().
    std::vector<Leaf> inTreeOrder() const;
    /// The active voxels of every leaf added, and their box. Not thread-safe against add().
    PackedStats stats() const;

  private:
    struct Local {
        std::vector<std::unique_ptr<char[]>> chunks;
        char* at = nullptr;
        std::size_t left = 0;  // bytes usable at `at`, slack excluded
        std::vector<Leaf> leaves;
        PackedStats stats;
    };
    tbb::enumerable_thread_specific<Local> mLocal;
};

/// Writes to @p path what openvdb::io::File writes, with COMPRESS_ACTIVE_MASK and the file
/// metadata {creator: palp}, for a float grid with @p grid's name, metadata, transform and
/// background whose leaves are @p leaves (its tree holds nothing else: no tiles, every internal
/// node made by adding the leaves), byte for byte but for the random UUID. @p grid's own tree is
/// not read. OpenVDB's file metadata is added as OpenVDB adds it (file_mem_bytes: the memory of
/// that grid, every leaf's buffer allocated). The file appears whole at @p path or not at all
/// (AtomicFile).
/// @throw IoError naming @p path when it cannot be written.
PackedStats writePackedVdb(const openvdb::FloatGrid& grid, const PackedLeaves& leaves,
                           const std::filesystem::path& path);

}  // namespace palp::volume::detail
