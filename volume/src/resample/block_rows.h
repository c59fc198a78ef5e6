#pragma once
/// @file
/// Internal to palp_volume: the resampler's row kernel over whole rows of leaf blocks, for
/// lattices whose x rows keep the normal coordinate and the in-plane row coordinate and whose
/// slices all share their column coordinates (axial series, with or without gantry tilt, the
/// common CT). A row of blocks along x shares each of its 64 voxel rows' slice pair, blend
/// weight and pixel rows, so a voxel row's set-up is paid once for the whole width of the
/// lattice, and each pixel row's column interpolation is computed once per row of blocks.
/// The values are the per-block kernel's (fillBracketedBlock), bit for bit.

#include <cstdint>
#include <vector>

#include "resample/slice_sampler.h"

namespace palp::volume::detail {

/// One thread's working memory, reused from row to row of blocks.
struct BlockRowScratch {
    std::vector<float> values;          // the row's blocks, kLeafDim^3 values each, leaf order
    std::vector<int> ci;                // by voxel along x: the clamped pixel column
    std::vector<double> fc, gc;         // its fraction and 1 - fraction
    std::vector<std::uint32_t> inside;  // all ones where the column lies inside the slices
    std::vector<double> cache;          // column interpolations of pixel rows (kCacheSlots rows)
    std::vector<const float*> tags;     // the pixel row each cache slot holds
    std::vector<char> candidate;        // by block of the row: may hold active voxels (fillTree)
};

/// Whether @p ctx's lattice and slices suit fillBlockRow (then every block of a row of blocks
/// has the same normal range, so the same slice bracket).
bool blockRowsApply(const FillContext& ctx);

/// Fills blocks @p first..@p last (block indices along x) of the row of blocks at block
/// coordinates (@p by, @p bz), bracketed by sorted slices [@p bracket, @p bracketEnd], into
/// @p scratch.values: block i at (i - first) * kLeafDim^3, in leaf order; every voxel holds its
/// value when active (passes the threshold, differs from the background, lies inside the
/// slices) and the background otherwise.
void fillBlockRow(const FillContext& ctx, int by, int bz, int first, int last, std::size_t bracket,
                  std::size_t bracketEnd, BlockRowScratch& scratch);

}  // namespace palp::volume::detail
