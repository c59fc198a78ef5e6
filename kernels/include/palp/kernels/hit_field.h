#pragma once
/// @file
/// HitField: first-hit acceleration for one threshold over a VolumeView (volume_ray.h).

#include <cstddef>
#include <cstdint>
#include <vector>

#include "palp/kernels/volume_view.h"

namespace palp::kernels {

/// First-hit acceleration for one threshold (the fast path of firstHit() and traceFirstHit()).
/// It holds, for every padded block copy of a VolumeView that can reach the threshold, one bit
/// per cell: set when the cell's trilinear values can reach it (its corner maximum, raised by the
/// same hair as the 4^3 sub-block bounds); and for every table block one 32-bit entry with the
/// index of its copy's mask and the Chebyshev distance in blocks (at most kFarBlocks) to the
/// nearest block that has such a cell.
///
/// With a field the march takes the ray's samples on one float lattice in table coordinates
/// (not re-anchored per block), eight at a time with AVX2: the cells, blocks and mask bits of
/// eight samples in one step, the blend only at samples in cells that can reach the threshold,
/// and a jump over the samples that stay among blocks with none. Rays through soft tissue next
/// to bone cost a few vector steps instead of a block entry per 8^3 block and a blend per half
/// voxel. The samples are the same lattice samples as without a field at positions within
/// about 5e-4 voxel, so hits agree with the block-run path to that rounding, not bit for bit
/// (tests: the same hits and t within 1e-3 voxel on the bone-slab volume; on the 0.5 mm head CT,
/// 840,000 bench rays with no hit/miss difference and t within 3e-3 voxel, where grazing rays
/// amplify position rounding). With a field, scalar and AVX2, bundle and single ray give the
/// same bits.
///
/// Built at set-up, off the servo thread: 64 bytes (one cache line) per block copy that can
/// reach the threshold and 4 bytes per table block (`palp bench rays` prints the size and the
/// build time). A threshold change needs a new field, and a march whose threshold differs from
/// the field's ignores it.
///
/// @par Threading  Immutable after construction; any number of threads may trace with it.
///      The view must outlive the field.
/// @par Real-time  Construction allocates (set-up only); reading is noexcept.
class HitField {
  public:
    /// @throw palp::ValueError for a NaN threshold, or more block copies than the 27-bit mask
    ///        index holds.
    HitField(const VolumeView& view, float threshold);
    HitField(const HitField&) = delete;
    HitField& operator=(const HitField&) = delete;

    float threshold() const noexcept { return mThreshold; }
    const VolumeView& view() const noexcept { return *mView; }
    /// True when a first-hit march through @p view at @p threshold can use this field.
    bool matches(const VolumeView& view, float threshold) const noexcept {
        return &view == mView && threshold == mThreshold;
    }
    /// Heap bytes held.
    std::size_t bytes() const noexcept {
        return mMask.capacity() * sizeof(MaskLine) + mEntry.capacity() * sizeof(std::uint32_t) +
               mCopy.capacity() * sizeof(const float*) +
               mCopyOffset.capacity() * sizeof(std::int32_t);
    }
    /// Block copies that have at least one cell that can reach the threshold.
    std::size_t hotCopies() const noexcept { return mHotCopies; }

    // Internal layout, read by the marcher.
    static constexpr int kCells = 512;
    static constexpr int kMaskWords = kCells / 32;  ///< 16 words: one 64-byte cache line
    static constexpr std::uint8_t kFarBlocks = 16;
    static constexpr int kDistanceBits = 5;  ///< low bits of an entry: the block distance
    /// Table block @p block's entry: (mask index << kDistanceBits) | block distance. Mask 0 is
    /// all clear (the blocks with no cell that can reach the threshold share it).
    std::uint32_t entry(std::size_t block) const noexcept { return mEntry[block]; }
    /// 0 when the block has a cell that can reach the threshold, else the Chebyshev distance in
    /// blocks to the nearest block that has one (at most kFarBlocks): the (2D - 1)^3 blocks
    /// around a block at distance D hold no such cell.
    unsigned blockDistance(std::size_t block) const noexcept {
        return mEntry[block] & ((1u << kDistanceBits) - 1u);
    }
    /// The 16-word mask of table block @p block's copy: cell (x, y, z), local index
    /// l = (x * 8 + y) * 8 + z, is bit l % 32 of word l / 32.
    const std::uint32_t* blockMask(std::size_t block) const noexcept {
        return mMask[mEntry[block] >> kDistanceBits].w;
    }
    /// True when cell @p local (as in blockMask()) of table block @p block can reach the
    /// threshold.
    bool cellCanReach(std::size_t block, unsigned local) const noexcept {
        return ((blockMask(block)[local >> 5] >> (local & 31u)) & 1u) != 0;
    }
    /// The padded block copy (as detail::ViewTable::data) of mask index @p mask > 0: a small
    /// array (8 bytes per copy that can reach the threshold) that stays cached where the table's
    /// pointers (8 bytes per table block) would miss.
    const float* maskCopy(std::uint32_t mask) const noexcept { return mCopy[mask]; }
    /// The same as an offset in floats from detail::ViewTable::padded (mask 0: 0), for gathers;
    /// valid when the padded buffer has fewer than 2^31 - 1024 floats.
    const std::int32_t* maskCopyOffsets() const noexcept { return mCopyOffset.data(); }
    /// maskCopy() of every mask index, as an array (for prefetching).
    const float* const* maskCopies() const noexcept { return mCopy.data(); }
    /// True when maskCopyOffsets() holds the offsets (the padded buffer has fewer than
    /// 2^31 - 1024 floats, so 32-bit gathers reach every copy); else they are all 0.
    bool copyOffsetsValid() const noexcept { return mCopyOffsetsValid; }
    /// The entries (per table block) and the masks (16 words per mask index), for gathers.
    const std::uint32_t* entries() const noexcept { return mEntry.data(); }
    const std::uint32_t* masks() const noexcept { return mMask.front().w; }

  private:
    struct alignas(64) MaskLine {
        std::uint32_t w[kMaskWords];
    };
    const VolumeView* mView;
    float mThreshold;
    std::vector<std::uint32_t> mEntry;      ///< per table block: entry()
    std::vector<MaskLine> mMask;            ///< per mask index (0: all clear)
    std::vector<const float*> mCopy;        ///< per mask index: maskCopy()
    std::vector<std::int32_t> mCopyOffset;  ///< per mask index: maskCopyOffsets()
    bool mCopyOffsetsValid = false;
    std::size_t mHotCopies = 0;
};

}  // namespace palp::kernels
