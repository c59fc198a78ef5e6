#pragma once
/// @file
/// An indexed triangle mesh: the plain data that volume's mesh I/O and iso-surfaces produce and
/// the kernels' Embree scenes and refit BVH take.

#include <cstdint>
#include <vector>

namespace palp {

/// An indexed triangle mesh in world metres.
/// @par Threading  A plain value.
struct TriangleMesh {
    std::vector<float> positions;        ///< #V by 3 (x, y, z), metres
    std::vector<std::uint32_t> indices;  ///< #T by 3 vertex indices
    std::size_t vertexCount() const noexcept { return positions.size() / 3; }
    std::size_t triangleCount() const noexcept { return indices.size() / 3; }
};

}  // namespace palp
