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

namespace detail {
struct ViewTable;  // kernels/src/view_table.h
struct ViewAccess;
}  // namespace detail

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

    /// Releases the block table.
    ~VolumeView();

  private:
    friend struct detail::ViewAccess;
    void build(detail::ViewTable& table);  // the constructor's work, into the table
    openvdb::FloatGrid::ConstPtr mGrid;
    /// The block table the marcher reads (detail::ViewTable, internal to the kernels:
    /// kernels/src/view_table.h), constructed in place here so that reading it costs what reading
    /// a member does.
    alignas(8) std::byte mTable[120];
    /// Padded copies of the blocks that are not constant, then one shared copy per distinct
    /// constant.
    std::vector<float> mPadded;
    std::vector<float> mSubMax;  ///< ViewTable::subMax
    Eigen::Vector3d mWorldOrigin = Eigen::Vector3d::Zero();
    double mVoxelSize = 1;
    double mInvVoxelSize = 1;
    float mBackground = 0;
    bool mEmpty = true;
};

}  // namespace palp::kernels
