#pragma once
/// @file
/// Trilinear sampling of a FloatGrid at world positions.

#include <openvdb/openvdb.h>

namespace palp::kernels {

/// Samples @p grid trilinearly at @p worldPos (metres) through @p acc.
/// Outside the active voxels the grid's background value takes part in the interpolation.
/// @par Threading  The accessor caches nodes: give each thread its own accessor.
/// @par Real-time  noexcept, no allocation.
float sampleWorld(const openvdb::FloatGrid::ConstAccessor& acc,
                  const openvdb::math::Transform& xform, const openvdb::Vec3d& worldPos) noexcept;

/// Same, in index space (voxel centres at integer coordinates).
float sampleIndex(const openvdb::FloatGrid::ConstAccessor& acc,
                  const openvdb::Vec3d& indexPos) noexcept;

}  // namespace palp::kernels
