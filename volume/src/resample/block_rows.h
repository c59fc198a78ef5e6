#pragma once
/// @file
/// Internal to palp_volume: the resampler's row kernel over whole rows of leaf blocks, for
/// lattices whose rows along one axis keep the normal coordinate and the in-plane row
/// coordinate and whose slices all share their column coordinates (axial series with or without
/// gantry tilt, the common CT, and coronal or sagittal stacks along the patient axes). A row of
/// blocks shares each of its 64 voxel rows' slice pair, blend weight and pixel rows, so a voxel
/// row's set-up is paid once for the whole width of the lattice, and each pixel row's column
/// interpolation is computed once per row of blocks.
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

/// The lattice axis along which @p ctx's rows of blocks run (the per-block kernel's row axis,
/// along which the normal coordinate does not change), or -1 when its lattice and slices do not
/// suit fillBlockRow. Every block of a row of blocks then has the same normal range, so the same
/// slice bracket.
int blockRowAxis(const FillContext& ctx);

/// Fills blocks @p first..@p last (block indices along axis @p a) of the row of blocks at block
/// coordinates @p rowB, @p rowC along the next two axes ((a + 1) % 3, (a + 2) % 3), bracketed
/// by sorted slices [@p bracket, @p bracketEnd], into @p scratch.values: block i at (i - first)
/// * kLeafDim^3, in leaf order; every voxel holds its value when active (passes the threshold,
/// differs from the background, lies inside the slices) and the background otherwise.
void fillBlockRow(const FillContext& ctx, int a, int rowB, int rowC, int first, int last,
                  std::size_t bracket, std::size_t bracketEnd, BlockRowScratch& scratch);

}  // namespace palp::volume::detail
