#pragma once
/// @file
/// Voxelisation of a scan (palp::volume::Volume) into a regular hexahedral mesh: tissue cells
/// where the scan value is above a threshold, per-element Young's modulus from a transfer
/// function of the value, and the nodes inside a bone mask as fixed-node set.

#include <functional>
#include <limits>
#include <vector>

#include "palp/fem/hex_mesh.h"
#include "palp/volume/volume.h"

namespace palp::fem {

/// Options of voxelizeVolume().
struct VoxelizeOptions {
    /// Element edge h, metres (> 0). Independent of the scan's voxel size.
    double elementSize = 5e-3;
    /// A cell is tissue when the scan value sampled (trilinearly) at its centre is above this
    /// (scan units, e.g. HU).
    double tissueThreshold = -200.0;
    /// A tissue cell is bone when its centre value is above this; its nodes go to
    /// VoxelizedMesh::boneNodes. +infinity: no bone.
    double boneThreshold = std::numeric_limits<double>::infinity();
    /// Young's modulus in pascals (finite, > 0) of a tissue cell from its centre value.
    /// Empty: a constant 5 kPa.
    std::function<double(double)> youngsFromValue;
    /// Keep only the largest connected body (cells sharing a node are connected) and drop
    /// islands (noise, a separate object), since FemModel accepts one body only.
    bool keepLargestComponent = true;
    /// Upper bound on lattice cells, guarding against a tiny element size on a large scan.
    long maxCells = 20'000'000;
};

/// Throws palp::ValueError naming the field (`voxelize elementSize: expected a value in [1e-06,
/// 0.1] m, found 0`) unless elementSize is in bounds::kSpacing, tissueThreshold in
/// bounds::kVolumeValue, boneThreshold in bounds::kVolumeValue or +infinity (no bone) and
/// maxCells >= 1.
/// @throw palp::ValueError
void validate(const VoxelizeOptions& options);

/// Result of voxelizeVolume().
struct VoxelizedMesh {
    HexMesh mesh;                ///< lattice over the scan's active bounds, void outside tissue
    std::vector<int> boneNodes;  ///< sorted active nodes of bone cells (to fix as supports)
    int droppedCells = 0;        ///< tissue cells removed with islands (keepLargestComponent)
};

/// Voxelises @p volume: the lattice covers the world box of the active voxels (each voxel a cube
/// of the volume's voxel size) with cubes of edge `options.elementSize`, starting at the box's
/// minimum corner; node positions are world metres in the volume's frame (HexMesh::origin()).
/// @throw palp::ValueError for options validate() refuses, an empty volume, a
/// lattice above maxCells, no cell above the tissue threshold, a transfer function that returns a
/// non-finite or non-positive modulus (the message names the value).
VoxelizedMesh voxelizeVolume(const volume::Volume& volume, const VoxelizeOptions& options);

}  // namespace palp::fem
