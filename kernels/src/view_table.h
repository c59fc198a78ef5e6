#pragma once
/// @file
/// Internal to the ray kernels (kernels/src; tests and benchmarks reach it through a private
/// include): the block table of a VolumeView that the marcher reads, and the access to it.

#include <array>
#include <cstddef>
#include <cstdint>
#include <new>
#include <vector>

#include "palp/kernels/volume_view.h"

namespace palp::kernels::detail {

/// A VolumeView's flat table of 8^3 blocks and their padded 9^3 copies.
struct ViewTable {
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

/// Reaches the table a VolumeView holds in place.
struct ViewAccess {
    static const ViewTable& table(const VolumeView& v) noexcept {
        return *std::launder(reinterpret_cast<const ViewTable*>(v.mTable));
    }
    static ViewTable& table(VolumeView& v) noexcept {
        return *std::launder(reinterpret_cast<ViewTable*>(v.mTable));
    }
    static constexpr std::size_t kBytes = sizeof(VolumeView::mTable);
};
static_assert(sizeof(ViewTable) == ViewAccess::kBytes && alignof(ViewTable) <= 8,
              "VolumeView::mTable must hold a ViewTable exactly");

/// The block table of @p view. @par Real-time noexcept.
inline const ViewTable& viewTable(const VolumeView& view) noexcept {
    return ViewAccess::table(view);
}

}  // namespace palp::kernels::detail
