#pragma once
/// @file
/// Internal to palp_volume_core: leaves kept as the file stores them, not as a grid, and the
/// .vdb written from them (palp convert: the grid's values are never held in memory). Written
/// without libopenvdb (its headers' coordinates and masks only): `palp convert` does not load
/// it (docs/volumes.md).

#include <openvdb/math/Coord.h>
#include <openvdb/util/NodeMasks.h>
#include <tbb/enumerable_thread_specific.h>

#include <Eigen/Core>
#include <cstddef>
#include <cstdint>
#include <filesystem>
#include <memory>
#include <string>
#include <vector>

#include "palp/volume/volume_info.h"

namespace palp::volume::detail {

/// Bytes of a leaf's buffers as LeafNode::writeBuffers writes them under COMPRESS_ACTIVE_MASK
/// alone (no half floats) when every inactive value is the background: the value mask, the
/// metadata byte and the @p active values.
constexpr std::size_t packedLeafBytes(std::size_t active) noexcept {
    return 64 + 1 + active * sizeof(float);
}

/// Writes those bytes for a leaf whose value mask is @p words (64-bit words in index order) and
/// whose 512 values are @p values, to @p dst; returns the end of what it wrote. Every inactive
/// value must equal the grid's background (the caller's promise: the mask alone restores them).
/// May store up to sizeof(float) bytes past the end it returns (@p dst needs that slack).
char* packLeafBuffers(const std::uint64_t (&words)[8], const float* values, char* dst) noexcept;

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

/// What a packed file's grid is besides its leaves: its metadata, its index-to-world transform
/// (voxel (i, j, k) centred at lo + step .* (i, j, k), metres; a uniform scale when the three
/// steps are equal) and its background.
struct PackedGrid {
    VolumeInfo info;
    Eigen::Vector3d step = Eigen::Vector3d::Zero();
    Eigen::Vector3d lo = Eigen::Vector3d::Zero();
    float background = 0;
};

/// The map an OpenVDB transform made as resample() makes it (worldFromIndex) holds for
/// @p step and @p lo, and so writes: voxel (i, j, k) at scale .* (i, j, k) + translation.
/// Equal steps give a UniformScaleTranslateMap of them. Unequal ones give a ScaleTranslateMap,
/// which Transform's constructor simplifies through its affine matrix: the scale it keeps is
/// (step + lo) - lo on each axis, not always the step (a 0.48 mm step at -0.1 m loses its last
/// bits), and scales within 1e-15 of the first become a UniformScaleTranslateMap of it.
struct StoredMap {
    bool uniform = true;
    Eigen::Vector3d scale = Eigen::Vector3d::Zero();
    Eigen::Vector3d translation = Eigen::Vector3d::Zero();
};
StoredMap storedMap(const Eigen::Vector3d& step, const Eigen::Vector3d& lo);

/// Writes to @p path what openvdb::io::File writes, with COMPRESS_ACTIVE_MASK and the file
/// metadata {creator: palp}, for a float grid named kScanGridName with @p grid's metadata
/// (writeInfo()), transform (the one resample() gives: Transform::createLinearTransform of the
/// step, then postTranslate of lo; a ScaleTranslateMap for unequal steps) and background,
/// whose leaves are @p leaves (its tree holds nothing else: no tiles, every internal node made
/// by adding the leaves), byte for byte but for the random UUID. OpenVDB's file metadata is
/// added as OpenVDB adds it (file_mem_bytes: the memory of that grid, every leaf's buffer
/// allocated). The file appears whole at @p path or not at all (AtomicFile).
/// @throw IoError naming @p path when it cannot be written.
PackedStats writePackedVdb(const PackedGrid& grid, const PackedLeaves& leaves,
                           const std::filesystem::path& path);

}  // namespace palp::volume::detail
