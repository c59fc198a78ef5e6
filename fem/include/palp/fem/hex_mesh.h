#pragma once
/// @file
/// HexMesh: a regular lattice of 8-node trilinear hexahedra (cubes of edge h), some cells of
/// which are active (a box, or a voxelised tissue mask), with per-element Young's modulus.
///
/// Numbering: node (i, j, k) of the lattice is `i + nx (j + ny k)`, cell (i, j, k) is
/// `i + cx (j + cy k)` with `cx = nx - 1` etc.; degrees of freedom are interleaved,
/// dof `3 n + c` is component c (x, y, z) of node n. Nodes that no active cell touches are
/// inactive: solvers hold them at zero and exclude them from mass and outputs.
/// Local node order inside an element is lexicographic with x fastest:
/// (0,0,0), (1,0,0), (0,1,0), (1,1,0), (0,0,1), (1,0,1), (0,1,1), (1,1,1).

#include <Eigen/Core>
#include <array>
#include <cstdint>
#include <vector>

namespace palp::fem {

/// One of the six faces of the lattice's bounding box.
enum class BoxFace { xMin, xMax, yMin, yMax, zMin, zMax };

/// Boundary surface as a triangle mesh (for Embree): positions in metres, counter-clockwise
/// seen from outside (outward normals).
struct SurfaceMesh {
    std::vector<Eigen::Vector3f> vertices;                ///< #V positions, metres
    std::vector<std::array<std::uint32_t, 3>> triangles;  ///< #T vertex indices
    std::vector<std::int32_t> vertexNode;                 ///< #V mesh node of each vertex
};

/// A regular hexahedral mesh with per-cell Young's modulus (0 marks a void cell).
class HexMesh {
  public:
    HexMesh() = default;

    /// A solid box of @p size metres starting at @p origin with @p nodeCounts nodes per axis
    /// (at least 2 each) and uniform Young's modulus @p youngsModulus (Pa). Cells must be cubes:
    /// `size[a] / (nodeCounts[a] - 1)` equal on all axes to 1e-9 relative.
    /// @throw palp::ValueError on non-positive sizes, fewer than 2 nodes, non-cubic cells.
    static HexMesh box(const Eigen::Vector3d& size, const std::array<int, 3>& nodeCounts,
                       double youngsModulus = 1.0,
                       const Eigen::Vector3d& origin = Eigen::Vector3d::Zero());

    /// A lattice of @p nodeCounts nodes with edge @p edge metres and the given per-cell Young's
    /// modulus (#cells, Pa; 0 = void, otherwise finite > 0).
    /// @throw palp::ValueError on bad counts, edge, moduli, or no active cell.
    static HexMesh fromCells(const std::array<int, 3>& nodeCounts, double edge,
                             const Eigen::Vector3d& origin, std::vector<double> cellYoungs);

    /// Node counts per axis.
    const std::array<int, 3>& nodeCounts() const { return mNodeCounts; }
    /// Cell counts per axis (node counts - 1).
    std::array<int, 3> cellCounts() const {
        return {mNodeCounts[0] - 1, mNodeCounts[1] - 1, mNodeCounts[2] - 1};
    }
    /// Element edge length h, metres.
    double edge() const { return mEdge; }
    /// Position of node (0,0,0), metres.
    const Eigen::Vector3d& origin() const { return mOrigin; }
    /// Number of lattice nodes (active and inactive).
    int nodeCount() const { return mNodeCounts[0] * mNodeCounts[1] * mNodeCounts[2]; }
    /// Number of lattice cells (active and void).
    int cellCount() const;
    /// Number of active cells (elements).
    int elementCount() const { return mElementCount; }
    /// Number of degrees of freedom, 3 * nodeCount().
    int dofCount() const { return 3 * nodeCount(); }

    /// Node index of lattice node (i, j, k).
    int node(int i, int j, int k) const { return i + mNodeCounts[0] * (j + mNodeCounts[1] * k); }
    /// Cell index of lattice cell (i, j, k).
    int cell(int i, int j, int k) const;
    /// Lattice coordinates (i, j, k) of node @p n.
    std::array<int, 3> nodeCoords(int n) const;
    /// Position of node @p n, metres.
    Eigen::Vector3d nodePosition(int n) const;
    /// The 8 nodes of cell @p c in local order (see file comment).
    std::array<int, 8> cellNodes(int c) const;

    /// Per-cell Young's modulus, Pa, #cells; 0 for void cells.
    const std::vector<double>& cellYoungs() const { return mCellYoungs; }
    /// True when cell @p c is an element.
    bool cellActive(int c) const { return mCellYoungs[static_cast<std::size_t>(c)] > 0.0; }
    /// Per-node flag, #nodes: 1 when an active cell touches the node.
    const std::vector<std::uint8_t>& nodeActive() const { return mNodeActive; }

    /// Active nodes on lattice face @p face (sorted).
    std::vector<int> faceNodes(BoxFace face) const;
    /// Active nodes whose position satisfies @p inside (e.g. a bone mask), sorted.
    template <class Predicate>
    std::vector<int> nodesWhere(Predicate inside) const {
        std::vector<int> out;
        for (int n = 0; n < nodeCount(); ++n) {
            if (mNodeActive[static_cast<std::size_t>(n)] && inside(nodePosition(n))) {
                out.push_back(n);
            }
        }
        return out;
    }

    /// Number of connected components of active cells (cells sharing a node are connected).
    int connectedComponents() const;

    /// Boundary faces of the active cells (faces between an active cell and a void cell or the
    /// outside), two triangles each, outward-oriented.
    SurfaceMesh boundarySurface() const;

  private:
    std::array<int, 3> mNodeCounts{0, 0, 0};
    double mEdge = 0.0;
    Eigen::Vector3d mOrigin = Eigen::Vector3d::Zero();
    std::vector<double> mCellYoungs;
    std::vector<std::uint8_t> mNodeActive;
    int mElementCount = 0;
};

}  // namespace palp::fem
