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

/// What voxelizeVolume() does with tissue inside bone (VoxelizeOptions::insideBone).
enum class InsideBone {
    keep,  ///< every cell above the tissue threshold is tissue (phantoms, bone-free scans)
    /// Tissue enclosed by bone is dropped: a tissue cell below the bone threshold with bone
    /// cells on both sides of it along at least two of the three lattice axes (the brain inside
    /// a skull, also where the scan stops short of the vertex or the skull base) unless it has a
    /// face on the air outside (skin, e.g. the nape under the skull base), and the bone
    /// cells that share no node with the tissue kept. What stays is the tissue between the skin
    /// and the outside of the bone, resting on the bone cells under it; tissue under a plate or
    /// slab open at its sides (one axis) stays.
    drop,
};

/// Options of voxelizeVolume().
struct VoxelizeOptions {
    /// Element edge h, metres (> 0). Independent of the scan's voxel size.
    double elementSize = 5e-3;
    /// A cell is tissue when the scan value sampled at its centre (trilinearly, or the nearest
    /// voxel's with nearestValue) is above this (scan units, e.g. HU).
    double tissueThreshold = -200.0;
    /// A tissue cell is bone when its centre value is above this; its nodes go to
    /// VoxelizedMesh::boneNodes. +infinity: no bone.
    double boneThreshold = std::numeric_limits<double>::infinity();
    /// Young's modulus in pascals (finite, > 0) of a tissue cell from its centre value.
    /// Empty: a constant 5 kPa. It may throw palp::ValueError (a value it has no modulus for):
    /// voxelizeVolume() passes that on.
    std::function<double(double)> youngsFromValue;
    /// A cell's centre value is the nearest voxel's (a label volume: a segmentation, whose
    /// trilinear blend of labels 1 and 3 would read as label 2) instead of the trilinear one.
    bool nearestValue = false;
    /// Tissue inside bone: kept (the default) or dropped (InsideBone::drop). Only matters with a
    /// finite boneThreshold.
    InsideBone insideBone = InsideBone::keep;
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
    /// Cells removed by InsideBone::drop: tissue enclosed by bone and bone cells that touch no
    /// kept tissue (before the islands are removed).
    int insideBoneCells = 0;
};

/// Voxelises @p volume: the lattice covers the world box of the active voxels (each voxel a cube
/// of the volume's voxel size) with cubes of edge `options.elementSize`, starting at the box's
/// minimum corner; node positions are world metres in the volume's frame (HexMesh::origin()).
/// @throw palp::ValueError for options validate() refuses, an empty volume, a
/// lattice above maxCells, no cell above the tissue threshold, a transfer function that returns a
/// non-finite or non-positive modulus (the message names the value).
VoxelizedMesh voxelizeVolume(const volume::Volume& volume, const VoxelizeOptions& options);

}  // namespace palp::fem
