#pragma once
/// @file
/// VolumeView: the flat, padded block table of a FloatGrid that the ray kernels read
/// (volume_ray.h).

#include <openvdb/openvdb.h>

#include <Eigen/Core>
#include <array>
#include <cstddef>
#include <cstdint>
#include <vector>

namespace palp::kernels {

/// Largest number of 8^3 blocks a VolumeView accepts (its table costs 16 bytes per block).
inline constexpr std::int64_t kMaxViewBlocks = std::int64_t{1} << 26;

/// Read-only flat view of a FloatGrid for ray marching. Holds a shared pointer to the grid and a
/// padded copy of its values (about 1.4x the leaf data, plus one shared copy per distinct
/// constant); changes to the grid after construction are not seen.
///
/// @par Threading  Immutable after construction: any number of threads may trace through one
///      view at the same time, with no per-thread state.
/// @par Real-time  Construction allocates and is for set-up threads; sampling and tracing are
///      noexcept and allocation-free.
class VolumeView {
  public:
    /// Builds the block table over the bounding box of @p grid's leaves and active tiles, grown
    /// by one block on each side, and the padded 9^3 copies. Forces delay-loaded leaf buffers
    /// into memory.
    /// @throw palp::ValueError for a null grid, a transform that is not an axis-aligned
    ///        isotropic scale plus translation, or a table above kMaxViewBlocks blocks.
    explicit VolumeView(openvdb::FloatGrid::ConstPtr grid);
    /// Not copyable: the block table points into this object's own buffer.
    VolumeView(const VolumeView&) = delete;
    VolumeView& operator=(const VolumeView&) = delete;

    /// Trilinear value at index position (x, y, z) (voxel centres at integers); background
    /// outside the table. Bit-compatible with sampleIndex() through an accessor (same weights,
    /// evaluated in float here).
    /// @par Real-time  noexcept, no allocation.
    float sampleIndex(double x, double y, double z) const noexcept;

    /// Voxel edge length, metres.
    double voxelSize() const noexcept { return mVoxelSize; }
    /// 1 / voxelSize(), per metre.
    double inverseVoxelSize() const noexcept { return mInvVoxelSize; }
    float background() const noexcept { return mBackground; }
    const openvdb::FloatGrid& grid() const noexcept { return *mGrid; }
    /// True when the grid has no leaves and no active tiles.
    bool empty() const noexcept { return mEmpty; }
    /// World position (metres) -> index position.
    Eigen::Vector3d indexFromWorld(const Eigen::Vector3d& w) const noexcept {
        return (w - mWorldOrigin) * mInvVoxelSize;
    }
    /// World position (metres) of index position (0, 0, 0).
    const Eigen::Vector3d& worldOrigin() const noexcept { return mWorldOrigin; }

    // Internal layout, read by the marcher (kept public for the kernels' free functions).
    struct Table {
        static constexpr int kPad = 9;  ///< padded block edge (8 own voxels + 1 halo)
        static constexpr int kPadded = kPad * kPad * kPad;
        std::array<std::int32_t, 3> origin{};  ///< index of the first voxel (multiple of 8)
        std::array<std::int32_t, 3> blocks{};  ///< blocks per axis
        /// Per block: kPadded values, x-major ((lx * 9 + ly) * 9 + lz), lx, ly, lz in 0..8; the
        /// layer 8 holds the neighbour block's layer 0 (background past the table).
        std::vector<const float*> data;
        std::vector<float> maxDilated;  ///< max over the block's padded copy
        std::vector<float> minDilated;  ///< min over the same
        /// Every padded copy (constant ones included) lies in one buffer starting here, so a
        /// gather can address any block's values with 32-bit offsets from this base.
        const float* padded = nullptr;
        std::size_t paddedSize = 0;  ///< floats in that buffer
        /// Per padded copy c (the one at padded + c * kPadded), 8 floats: for each 4^3 sub-block
        /// s = 4 (lx >> 2) + 2 (ly >> 2) + (lz >> 2) of the cells based in the block, an upper
        /// bound on every value a first-hit sample in those cells can take (the maximum of the
        /// sub-block's 5^3 corner values, raised by a hair for the rounding of the trilinear
        /// blend and for positions a rounding step outside the cell). A sample there can only
        /// reach a threshold above the bound, so the march skips such sub-blocks in a block it
        /// cannot skip whole.
        const float* subMax = nullptr;
        static constexpr int kSubBlocks = 8;
    };
    const Table& table() const noexcept { return mTable; }

  private:
    openvdb::FloatGrid::ConstPtr mGrid;
    Table mTable;
    /// Padded copies of the blocks that are not constant, then one shared copy per distinct
    /// constant.
    std::vector<float> mPadded;
    std::vector<float> mSubMax;  ///< Table::subMax
    Eigen::Vector3d mWorldOrigin = Eigen::Vector3d::Zero();
    double mVoxelSize = 1;
    double mInvVoxelSize = 1;
    float mBackground = 0;
    bool mEmpty = true;
};

}  // namespace palp::kernels
