#pragma once
/// @file
/// Exact slice-aware resampling of a SliceStack into an isotropic, axis-aligned sparse grid.

#include <functional>
#include <optional>

#include "palp/volume/resample_options.h"
#include "palp/volume/slice_stack.h"
#include "palp/volume/volume.h"

namespace palp::volume {

/// Resamples @p stack. Each output voxel centre p is located between the two slices that
/// bracket it along the common slice normal n; each of those slices is sampled bilinearly at
/// the foot of p on its own plane (using that slice's own position and steps), and the two
/// values are blended linearly by distance along n. A voxel centre exactly on a slice therefore
/// reproduces that slice's bilinear interpolation, whatever the tilt or spacing.
/// Voxels outside the slices' extent are background. Voxels whose value is below the threshold,
/// or equal to the background value, are inactive.
///
/// The output lattice is anchored at the smallest corner of the slices' world bounding box, so
/// an axis-aligned source with the same voxel size is reproduced exactly.
/// @throw ValueError for options checkResampleOptions() refuses, an empty stack, slices of
///        differing orientation or size, repeated positions, values checkStackValues() refuses,
///        or a lattice larger than maxVoxels.
/// @par Threading  Parallel inside (TBB); callable from any thread.
Volume resample(const SliceStack& stack, const ResampleOptions& options = {});

/// Re-grids a stored volume (a `.vdb`) with the same options: trilinear resampling onto an
/// isotropic lattice of options.voxelSize (default: the volume's own edge) when a voxel size or
/// crop is given, kept inside options.crop. A volume of non-cubic voxels (native spacing) is
/// re-gridded to cubic voxels of its smallest edge unless options.nativeSpacing keeps its
/// lattice (a crop then keeps its transform), so every consumer of load() sees cubic voxels; with
/// options.backgroundThreshold, active values below it (or equal to the background value) become
/// inactive. The default threshold is not applied: a stored volume had its threshold applied when
/// it was made (info.backgroundThreshold). With none of these the volume is returned as is, sharing
/// its grid. The result's info (threshold) is written into its grid's metadata; progress reports 1
/// when done.
/// @throw ValueError for a volume without a grid, options checkResampleOptions() refuses, or an
///        error OpenVDB raises re-gridding it (named as such);
///        Error("resample: cancelled") when the progress callback returns false.
/// @par Threading  Parallel inside (TBB); callable from any thread.
Volume resample(const Volume& source, const ResampleOptions& options = {});

}  // namespace palp::volume
