#pragma once
/// @file
/// Exact slice-aware resampling of a SliceStack into an isotropic, axis-aligned sparse grid.

#include <functional>
#include <optional>

#include "palp/volume/slice_stack.h"
#include "palp/volume/volume.h"

namespace palp::volume {

/// Progress callback: @p fraction in [0, 1]. Return false to cancel (the call then throws
/// palp::Error("cancelled")). Called from the calling thread only.
using ProgressFn = std::function<bool(double fraction)>;

/// Axis-aligned world box in metres (LPS).
struct WorldBox {
    Eigen::Vector3d min = Eigen::Vector3d::Zero();
    Eigen::Vector3d max = Eigen::Vector3d::Zero();
};

/// How far (as a fraction of the mean gap) a slice may lie off its even position for native
/// spacing to take the slices as evenly spaced.
inline constexpr double kNativeGapTolerance = 0.01;

struct ResampleOptions {
    /// Output voxel edge in metres; default: the finest input spacing (smallest of the in-plane
    /// steps and the smallest slice gap).
    std::optional<double> voxelSize;
    /// Keep the source's own spacing instead of an isotropic lattice: voxels of the column step
    /// x the row step x the slice gap, laid on the world axes the source's columns, rows and
    /// normal lie along, one voxel per pixel (no margin), centred on the pixel centres (a
    /// per-axis scale transform when the steps differ). For slices: needs columns, rows and
    /// normal along the patient axes, no gantry tilt and evenly spaced slices (within
    /// kNativeGapTolerance); otherwise resample() refuses (ValueError naming the slice and
    /// what was found) and the caller chooses a voxel size. A single slice is one voxel thick
    /// (the smaller in-plane step). For a stored volume: its grid is kept as stored (no
    /// re-gridding to cubic voxels, see resample(const Volume&)). Not with voxelSize.
    bool nativeSpacing = false;
    /// Values below this become inactive background; default -900 for CT, none
    /// (kNoBackgroundThreshold) for MR, so that no MR value (a field map's or a phase image's
    /// negative values) is lost, and 0 for a source of unknown modality. The source values below
    /// it are counted (VolumeInfo::valuesBelowThreshold).
    std::optional<float> backgroundThreshold;
    /// Keep only voxels inside this world box.
    std::optional<WorldBox> crop;
    /// Refuse outputs whose bounding lattice exceeds this many voxels (protects memory).
    std::uint64_t maxVoxels = std::uint64_t{2} << 30;
    ProgressFn progress;
};

/// Checks @p options against palp's bounds: voxelSize a voxel spacing (bounds::kSpacing) and not
/// with nativeSpacing,
/// backgroundThreshold a volume value (bounds::kVolumeValue), the crop box's corners positions
/// (bounds::kPosition) with min <= max, maxVoxels > 0. Both resample() overloads (and so load())
/// call it first.
/// @throw ValueError `resample: <field>: expected ..., found ...`.
void checkResampleOptions(const ResampleOptions& options);

/// The threshold that deactivates no value: the lowest volume value palp accepts
/// (bounds::kVolumeValue), so no value is below it.
inline constexpr float kNoBackgroundThreshold = -1e9f;

/// Background value written for inactive voxels: -1000 for CT (air), otherwise 0; never above
/// the threshold, unless there is none (kNoBackgroundThreshold): then only voxels equal to the
/// background (an MR's zeros) are inactive, and they read back as what they were.
float backgroundValueFor(const VolumeInfo& info, float threshold);
/// Default threshold: -900 HU for CT, none (kNoBackgroundThreshold) for MR, 0 otherwise (a
/// NIfTI, NRRD or MetaImage file or an array does not say its modality; the values it loses are
/// counted). Until issue 37 it was 0 for MR too, which deactivated every negative value: a field
/// map in Hz kept 28,515 of 141,900 voxels and phase images lost half their range, without a
/// word.
float defaultBackgroundThreshold(const VolumeInfo& info);

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
