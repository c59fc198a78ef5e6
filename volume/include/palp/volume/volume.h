#pragma once
/// @file
/// Volume: a scan as a sparse OpenVDB grid with a world transform and non-identifying metadata.

#include <openvdb/openvdb.h>

#include <algorithm>
#include <array>
#include <cstdint>
#include <string>

#include "palp/volume/volume_info.h"

namespace palp::volume {

/// A scan as a sparse grid. `grid` is named "scan"; its transform maps index space to world
/// metres in the DICOM patient frame (LPS: +x left, +y posterior, +z superior). Voxels are
/// axis-aligned (a scale and translation) and cubic, except for a grid made with native spacing
/// (ResampleOptions::nativeSpacing), whose voxels may have a different edge along each axis;
/// load() re-grids such a grid to cubic voxels unless asked to keep it, so the kernels, the
/// mesher and the haptics only ever see cubic voxels. Inactive voxels hold the grid's
/// background value (e.g. -1000 HU of air); active voxels hold values in `info.valueUnits`.
///
/// @par Threading  Read-only use from many threads is safe if each thread has its own accessor.
struct Volume {
    openvdb::FloatGrid::Ptr grid;
    VolumeInfo info;

    /// Edge length of a cubic voxel in metres; for non-cubic voxels, the smallest edge.
    double voxelSize() const {
        const openvdb::Vec3d v = grid->transform().voxelSize();
        return std::min(v[0], std::min(v[1], v[2]));
    }
    /// Edge lengths of a voxel along index x, y, z in metres.
    openvdb::Vec3d voxelSizes() const { return grid->transform().voxelSize(); }
    /// Whether the voxels are cubic (the three edges equal, bit for bit).
    bool hasCubicVoxels() const {
        const openvdb::Vec3d v = grid->transform().voxelSize();
        return v[0] == v[1] && v[1] == v[2];
    }
    /// World box (metres) of the active voxels' centres; empty box for an empty grid.
    openvdb::BBoxd worldBounds() const;
};

/// Writes @p info into @p grid's metadata (keys prefixed "palp:").
void writeInfo(const VolumeInfo& info, openvdb::GridBase& grid);
/// Reads what writeInfo wrote; missing keys keep their defaults.
VolumeInfo readInfo(const openvdb::GridBase& grid);

/// Initialises OpenVDB once (thread-safe, idempotent). Every palp entry point that touches
/// OpenVDB calls it; applications may call it early.
void initialize();

}  // namespace palp::volume
