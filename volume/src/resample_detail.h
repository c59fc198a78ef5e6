#pragma once
/// @file
/// Internal to palp_volume (and its tests): the resampler's reference path.

#include "palp/volume/resample.h"

namespace palp::volume::detail {

/// resample(SliceStack) with every block filled voxel by voxel through the world-point
/// evaluation (bracketing slices found by search, in-plane coordinates by a matrix product),
/// not by the row kernel: the reference the fast path must reproduce.
Volume resampleVoxelByVoxel(const SliceStack& stack, const ResampleOptions& options = {});

}  // namespace palp::volume::detail
