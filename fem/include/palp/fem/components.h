#pragma once
/// @file
/// The pieces of a voxelised body and which of them the supports hold: what makes any scan's
/// tissue solvable. A CT gives more than one body: islands of tissue (cartilage, hair, the
/// table, a loose ear lobe), pieces joined to the rest by one edge or one corner only (which
/// hinge about it), parts that touch nothing fixed. Each such piece can move as a rigid body, so
/// its stiffness is singular: an implicit solver's factorisation fails and an explicit one lets
/// it drift. anchorBody() finds the pieces and keeps exactly those the fixed nodes hold.
///
/// Rule (docs/algorithms.md section 5):
/// * A piece is a set of active cells joined through shared faces (6-connected cells). Cells
///   that share only an edge or a corner are different pieces: a hexahedron turns about a
///   shared edge.
/// * A piece is anchored when its own nodes include three fixed nodes not on one line (a face
///   of a bone cell, a support face): then no rigid motion of it leaves the fixed nodes in
///   place.
/// * Anchored pieces are kept (a body may have several), the others dropped (an island would
///   fall away from the finger; a piece hanging on one edge would swing). Nothing is fixed that
///   the caller did not fix.
/// * The lattice is cropped to the kept cells (void margins cost memory in every per-dof
///   vector), then padded with void cells up to a multiple of 4 cells per axis, so the regions'
///   coarse levels of detail 2 and 4 divide it on any scan.

#include <Eigen/Core>
#include <array>
#include <vector>

#include "palp/fem/hex_mesh.h"

namespace palp::fem {

/// One face-connected piece of a body.
struct BodyPiece {
    int cells = 0;                ///< active cells (elements)
    int fixedNodes = 0;           ///< its nodes that are fixed
    bool anchored = false;        ///< three of its fixed nodes are not on one line
    Eigen::Vector3d lo{0, 0, 0};  ///< world box of its cells, m
    Eigen::Vector3d hi{0, 0, 0};
};

/// The face-connected pieces of @p mesh's active cells, largest first, and for each cell the
/// index of its piece in that order (-1 for a void cell). @p fixedNode: per lattice node, non-zero
/// when the node is fixed (#nodes).
/// @throw palp::ValueError when fixedNode's size is not mesh.nodeCount().
std::vector<BodyPiece> bodyPieces(const HexMesh& mesh, const std::vector<std::uint8_t>& fixedNode,
                                  std::vector<int>* cellPiece = nullptr);

/// Result of anchorBody().
struct AnchoredBody {
    HexMesh mesh;                    ///< the anchored pieces on the cropped lattice
    std::vector<int> fixedNodes;     ///< sorted: the given fixed nodes still active, renumbered
    std::vector<BodyPiece> kept;     ///< largest first
    std::vector<BodyPiece> dropped;  ///< largest first
    int droppedCells = 0;
    /// Lattice index of the cropped lattice's node (0, 0, 0) in the given lattice.
    std::array<int, 3> offset{0, 0, 0};
    /// Node n of the given lattice is node `renumber(n)` here (-1 when outside the crop).
    int renumber(int n, const HexMesh& given) const noexcept;
};

/// Keeps the pieces of @p mesh that @p fixedNodes anchor (see the file comment), drops the
/// others and crops the lattice to what stays.
/// @throw palp::ValueError naming the count when no piece is anchored (`deformable supports:
/// expected a piece of tissue held by three fixed nodes not on one line, found 3 pieces and none
/// held (largest: 812 cells, 2 fixed nodes)`), or for a fixed node outside the lattice.
AnchoredBody anchorBody(const HexMesh& mesh, const std::vector<int>& fixedNodes);

/// Refuses a mesh with a piece @p fixedNodes do not hold: throws palp::ValueError naming the
/// piece (`deformable supports: expected every piece of the body held by three fixed nodes not
/// on one line, found piece 2 of 3 (12 cells, 2 fixed nodes, box ... mm) free to move as a rigid
/// body`), or for a fixed node outside the lattice.
void requireAnchored(const HexMesh& mesh, const std::vector<int>& fixedNodes);

}  // namespace palp::fem
