#pragma once
/// @file
/// How slices become a grid: the resampler's options, their check, and the background
/// threshold's defaults. Free of OpenVDB (palp_volume_core).

#include <Eigen/Core>
#include <cstdint>
#include <functional>
#include <optional>

#include "palp/volume/volume_info.h"

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

}  // namespace palp::volume
