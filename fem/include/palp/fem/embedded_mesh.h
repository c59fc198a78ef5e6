#pragma once
/// @file
/// EmbeddedMesh: a triangle mesh (a tumour, cartilage: a dynamic inhomogeneity, docs/algorithms.md
/// section 10) embedded in a hexahedral FEM lattice, so that it deforms with the tissue. Each
/// vertex is tied to one active cell by the cell's 8 trilinear shape functions; its deformed
/// position is x = X + sum_a N_a(X) u_a, with X the rest position and u_a the displacements of
/// the cell's nodes. Trilinear interpolation is continuous across cell faces, so the choice
/// between neighbouring cells of a vertex on a shared face, edge or node does not matter, and it
/// reproduces affine displacement fields exactly.
///
/// Vertices outside every active cell (in a void cell or outside the lattice, e.g. a vertex a
/// rounding error off the tissue boundary) are tied to the nearest active cell with their
/// local coordinates clamped to [0, 1]^3: they move with the nearest point of that cell.
/// Vertices farther than one element edge from every active cell are refused.
///
/// Cost: construction O(#V * 64) cell tests (0.5 ms for 642 vertices, 7 ms for 10242); about
/// 160 bytes per vertex; update() O(#V * 8), 24 multiply-adds per vertex, no allocation: 8 us
/// for 642 vertices (a subdivision-3 icosphere's count), 130 us for 10242 (release build,
/// random vertices in a 20 x 10 x 20 lattice, one core of a shared 2-core machine under load).

#include <Eigen/Core>
#include <array>
#include <cstdint>
#include <span>
#include <vector>

#include "palp/base/triangle_mesh.h"
#include "palp/fem/fem_model.h"
#include "palp/fem/hex_mesh.h"

namespace palp::fem {

/// A triangle mesh tied to the cells of a HexMesh by trilinear weights.
/// @par Threading  Built on one thread (off the servo thread), then immutable: any number of
///      threads may call update() at once, each with its own output.
class EmbeddedMesh {
  public:
    /// Distance from the nearest active cell, in element edges, up to which a vertex counts as
    /// inside it (rounding of float positions on a cell face); farther ones count as clamped.
    static constexpr double kInsideTolerance = 1e-6;

    /// Ties every vertex of @p rest (world metres, the frame of @p mesh's node positions) to
    /// the active cell of @p mesh that contains it, or to the nearest active cell (clamped, see
    /// the file comment). Keeps a copy of @p rest (restMesh()) for building a RefitMesh.
    /// @throw palp::ValueError for a mesh without elements, an empty @p rest (no vertex), a
    ///        position count not a multiple of 3, a triangle index count not a multiple of 3 or
    ///        an index out of range, a non-finite vertex, or a vertex farther than one element
    ///        edge from every active cell (the message names the vertex and its position).
    EmbeddedMesh(const HexMesh& mesh, const TriangleMesh& rest);
    /// As above, on the model's mesh.
    EmbeddedMesh(const FemModel& model, const TriangleMesh& rest);

    /// Writes the deformed positions x = X + sum_a N_a u_a (#V by 3, metres) for the nodal
    /// displacements @p u (dofCount() values, interleaved as HexMesh: dof 3 n + c). Non-finite
    /// displacements give non-finite positions (RefitMesh::refit rejects them).
    /// @return false, writing nothing, when @p u has not dofCount() entries or @p positions
    ///         not 3 #V.
    /// @par Real-time  noexcept, no allocation, no lock, O(#V * 8).
    bool update(const Eigen::VectorXd& u, std::span<float> positions) const noexcept;
    /// As above in double precision (tests, offline use).
    bool update(const Eigen::VectorXd& u, std::span<double> positions) const noexcept;

    /// Number of vertices #V.
    std::size_t vertexCount() const noexcept { return mCell.size(); }
    /// Size of the displacement vector update() takes (the mesh's dofCount()).
    int dofCount() const noexcept { return mDofCount; }
    /// The rest mesh as given (positions #V by 3, metres; indices #T by 3).
    const TriangleMesh& restMesh() const noexcept { return mRestMesh; }
    /// Cell (HexMesh cell index, always active) that vertex @p v is tied to.
    int cellOf(std::size_t v) const noexcept { return mCell[v]; }
    /// The 8 trilinear weights of vertex @p v in its cell, in HexMesh's local node order (they
    /// sum to 1).
    std::array<double, 8> weights(std::size_t v) const noexcept;
    /// Local coordinates of vertex @p v in its cell, each in [0, 1] (clamped).
    const Eigen::Vector3d& localCoordinates(std::size_t v) const noexcept { return mLocal[v]; }
    /// Number of vertices outside every active cell (tied to the nearest one, clamped).
    int clampedCount() const noexcept { return mClampedCount; }
    /// Largest distance of a clamped vertex from its cell, metres (0 when none is clamped).
    double maxClampDistance() const noexcept { return mMaxClampDistance; }
    /// Sorted distinct lattice nodes whose displacements update() reads (the nodes of the cells
    /// in use): what a solver that publishes only some nodes (fem::AsyncRegions watchNodes)
    /// must publish for this mesh.
    const std::vector<int>& nodes() const noexcept { return mNodes; }

  private:
    template <class T>
    bool updateImpl(const Eigen::VectorXd& u, std::span<T> positions) const noexcept;

    TriangleMesh mRestMesh;
    std::vector<Eigen::Vector3d> mRest;             // #V rest positions (double)
    std::vector<Eigen::Vector3d> mLocal;            // #V local coordinates in [0, 1]^3
    std::vector<int> mCell;                         // #V cell indices
    std::vector<std::array<std::int32_t, 8>> mDof;  // #V first dof (3 n) of the 8 cell nodes
    std::vector<std::array<double, 8>> mWeight;     // #V trilinear weights
    std::vector<int> mNodes;
    int mDofCount = 0;
    int mClampedCount = 0;
    double mMaxClampDistance = 0;
};

}  // namespace palp::fem
