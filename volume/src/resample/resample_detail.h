#pragma once
/// @file
/// Internal to palp_volume (and its tests): the resampler's reference path.

#include "lazy_stack.h"
#include "palp/volume/resample.h"

namespace palp::volume::detail {

/// resample() of @p lazy, the same grid as resample(SliceStack) of the decoded stack. Each slice
/// is decoded (in parallel, a band at a time) when the first block that reads it comes and
/// released when the last has passed; slices no block reads (outside a crop) are decoded and
/// checked at the end, so a damaged file is refused whatever the crop. Leaves @p lazy's values
/// released.
/// @throw what decode throws (within a band, the lowest slice's error first); FormatError
///        naming the slice for a value checkStackValues() refuses; what resample() throws.
Volume resampleLazy(LazySliceStack& lazy, const ResampleOptions& options);

/// resample(SliceStack) with every block filled voxel by voxel through the world-point
/// evaluation (bracketing slices found by search, in-plane coordinates by a matrix product),
/// not by the row kernel: the reference the fast path must reproduce.
Volume resampleVoxelByVoxel(const SliceStack& stack, const ResampleOptions& options = {});

/// resample(SliceStack) with the row kernel's scalar rows only (no AVX2 rows where the CPU has
/// AVX2): the vector rows must give the same grid, bit for bit.
Volume resampleScalarRows(const SliceStack& stack, const ResampleOptions& options = {});

/// resample(SliceStack) with every block filled by itself, never by whole rows of blocks
/// (fillBlockRow, which interpolates each pixel row's columns once per row of blocks): the rows
/// of blocks must give the same grid, bit for bit.
Volume resamplePerBlockRows(const SliceStack& stack, const ResampleOptions& options = {});

}  // namespace palp::volume::detail
