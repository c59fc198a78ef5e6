#pragma once
/// @file
/// Triangle meshes for Embree: loading from OBJ/STL/PLY (and anything else Assimp reads) and
/// iso-surfaces of a FloatGrid.

#include <openvdb/openvdb.h>

#include <cstdint>
#include <filesystem>
#include <vector>

namespace palp::kernels {

/// An indexed triangle mesh in world metres.
/// @par Threading  A plain value.
struct TriangleMesh {
    std::vector<float> positions;        ///< #V by 3 (x, y, z), metres
    std::vector<std::uint32_t> indices;  ///< #T by 3 vertex indices
    std::size_t vertexCount() const noexcept { return positions.size() / 3; }
    std::size_t triangleCount() const noexcept { return indices.size() / 3; }
};

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
/// @throw palp::ValueError for a non-finite iso value or an adaptivity outside [0, 1].
/// @par Threading  Parallel inside (TBB); any thread.
TriangleMesh isoSurface(const openvdb::FloatGrid& grid, double isoValue, double adaptivity = 0.0);

/// Writes @p mesh as a Wavefront OBJ (metres). For tests and debugging.
/// @throw palp::IoError.
void saveObj(const TriangleMesh& mesh, const std::filesystem::path& path);

}  // namespace palp::kernels
