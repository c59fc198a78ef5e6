#pragma once
/// @file
/// Triangle meshes from files and volumes: loading from OBJ/STL/PLY (and anything else Assimp
/// reads), iso-surfaces of a FloatGrid, and OBJ output.

#include <openvdb/openvdb.h>

#include <filesystem>

#include "palp/base/triangle_mesh.h"

namespace palp::volume {

/// Reads a triangle mesh (OBJ, STL ASCII/binary, PLY, and the other formats of Debian's
/// libassimp). All meshes of the file are merged; polygons are triangulated; positions are
/// multiplied by @p metresPerUnit (1e-3 for files in millimetres).
/// @throw palp::IoError when the file cannot be read, palp::FormatError when it holds no
///        triangles, palp::ValueError for a non-positive scale.
/// @par Threading  Any thread.
TriangleMesh loadMesh(const std::filesystem::path& path, double metresPerUnit = 1.0);

/// Iso-surface of @p grid at @p isoValue (value units) through openvdb::tools::volumeToMesh;
/// quads are split into two triangles. Positions are world metres. @p adaptivity in [0, 1]
/// merges flat regions (0 keeps every voxel-sized face).
/// @throw palp::ValueError for an iso value or grid background outside bounds::kVolumeValue,
///        an adaptivity outside [0, 1], or an error OpenVDB raises (NaN voxels, a singular
///        transform), named as the grid's.
/// @par Threading  Parallel inside (TBB); any thread.
TriangleMesh isoSurface(const openvdb::FloatGrid& grid, double isoValue, double adaptivity = 0.0);

/// Writes @p mesh as a Wavefront OBJ (metres). For tests and debugging.
/// @throw palp::IoError.
void saveObj(const TriangleMesh& mesh, const std::filesystem::path& path);

}  // namespace palp::volume
