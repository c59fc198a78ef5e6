#include "palp/fem/hex_mesh.h"

#include <cmath>
#include <numeric>
#include <sstream>
#include <string>

#include "index_cast.h"
#include "palp/base/error.h"
#include "palp/base/validate.h"

namespace palp::fem {

namespace {

void checkCounts(const std::array<int, 3>& counts) {
    for (int a = 0; a < 3; ++a) {
        if (counts[sz(a)] < 2 || counts[sz(a)] > 4096) {
            throwExpected("hex mesh node count along axis " + std::to_string(a), "2..4096",
                          std::to_string(counts[sz(a)]));
        }
    }
}

}  // namespace

HexMesh HexMesh::box(const Eigen::Vector3d& size, const std::array<int, 3>& nodeCounts,
                     double youngsModulus, const Eigen::Vector3d& origin) {
    checkCounts(nodeCounts);
    for (int a = 0; a < 3; ++a) {
        requirePositive("hex mesh box size along axis " + std::to_string(a), size[a], "m");
    }
    const double h = size[0] / (nodeCounts[0] - 1);
    for (int a = 1; a < 3; ++a) {
        const double ha = size[a] / (nodeCounts[sz(a)] - 1);
        if (std::abs(ha - h) > 1e-9 * h) {
            std::ostringstream s;
            s << "hex mesh box cell edge along axis " << a << ": expected cubic cells of " << h
              << " m, found " << ha << " m";
            throw ValueError(s.str());
        }
    }
    const std::size_t cells = sz(nodeCounts[0] - 1) * sz(nodeCounts[1] - 1) * sz(nodeCounts[2] - 1);
    return fromCells(nodeCounts, h, origin, std::vector<double>(cells, youngsModulus));
}

HexMesh HexMesh::fromCells(const std::array<int, 3>& nodeCounts, double edge,
                           const Eigen::Vector3d& origin, std::vector<double> cellYoungs) {
    checkCounts(nodeCounts);
    requirePositive("hex mesh element edge", edge, "m");
    HexMesh m;
    m.mNodeCounts = nodeCounts;
    m.mEdge = edge;
    m.mOrigin = origin;
    const std::size_t cells = sz(m.cellCount());
    if (cellYoungs.size() != cells) {
        std::ostringstream s;
        s << "hex mesh cell moduli: expected " << cells << " values, found " << cellYoungs.size();
        throw ValueError(s.str());
    }
    for (std::size_t c = 0; c < cells; ++c) {
        const double e = cellYoungs[c];
        if (!std::isfinite(e) || e < 0.0) {
            std::ostringstream s;
            s << "hex mesh Young's modulus of cell " << c
              << ": expected a finite value > 0 Pa (or 0 for void), found " << e;
            throw ValueError(s.str());
        }
    }
    m.mCellYoungs = std::move(cellYoungs);
    m.mNodeActive.assign(sz(m.nodeCount()), 0);
    for (int c = 0; c < static_cast<int>(cells); ++c) {
        if (!m.cellActive(c)) continue;
        ++m.mElementCount;
        for (int n : m.cellNodes(c)) m.mNodeActive[sz(n)] = 1;
    }
    if (m.mElementCount == 0) {
        throw ValueError(
            "hex mesh: expected at least one element with Young's modulus > 0, "
            "found an empty mesh");
    }
    return m;
}

int HexMesh::cellCount() const {
    return (mNodeCounts[0] - 1) * (mNodeCounts[1] - 1) * (mNodeCounts[2] - 1);
}

int HexMesh::cell(int i, int j, int k) const {
    return i + (mNodeCounts[0] - 1) * (j + (mNodeCounts[1] - 1) * k);
}

std::array<int, 3> HexMesh::nodeCoords(int n) const {
    const int nx = mNodeCounts[0];
    const int ny = mNodeCounts[1];
    return {n % nx, (n / nx) % ny, n / (nx * ny)};
}

Eigen::Vector3d HexMesh::nodePosition(int n) const {
    const auto ijk = nodeCoords(n);
    return mOrigin + mEdge * Eigen::Vector3d(ijk[0], ijk[1], ijk[2]);
}

std::array<int, 8> HexMesh::cellNodes(int c) const {
    const int cx = mNodeCounts[0] - 1;
    const int cy = mNodeCounts[1] - 1;
    const int i = c % cx;
    const int j = (c / cx) % cy;
    const int k = c / (cx * cy);
    const int n0 = node(i, j, k);
    const int sy = mNodeCounts[0];
    const int sz3 = mNodeCounts[0] * mNodeCounts[1];
    return {n0,       n0 + 1,       n0 + sy,       n0 + sy + 1,
            n0 + sz3, n0 + sz3 + 1, n0 + sz3 + sy, n0 + sz3 + sy + 1};
}

std::vector<int> HexMesh::faceNodes(BoxFace face) const {
    const int axis = static_cast<int>(face) / 2;
    const bool maxSide = static_cast<int>(face) % 2 == 1;
    const int target = maxSide ? mNodeCounts[sz(axis)] - 1 : 0;
    std::vector<int> out;
    for (int n = 0; n < nodeCount(); ++n) {
        if (mNodeActive[sz(n)] && nodeCoords(n)[sz(axis)] == target) out.push_back(n);
    }
    return out;
}

int HexMesh::connectedComponents() const {
    // Union-find over nodes: every active cell joins its 8 nodes.
    std::vector<int> parent(sz(nodeCount()));
    std::iota(parent.begin(), parent.end(), 0);
    auto find = [&parent](int x) {
        while (parent[sz(x)] != x) {
            parent[sz(x)] = parent[sz(parent[sz(x)])];
            x = parent[sz(x)];
        }
        return x;
    };
    for (int c = 0; c < cellCount(); ++c) {
        if (!cellActive(c)) continue;
        const auto nodes = cellNodes(c);
        const int r0 = find(nodes[0]);
        for (int a = 1; a < 8; ++a) {
            const int r = find(nodes[sz(a)]);
            if (r != r0) parent[sz(r)] = r0;
        }
    }
    int count = 0;
    for (int n = 0; n < nodeCount(); ++n) {
        if (mNodeActive[sz(n)] && find(n) == n) ++count;
    }
    return count;
}

SurfaceMesh HexMesh::boundarySurface() const {
    SurfaceMesh out;
    std::vector<std::int32_t> vertexOfNode(sz(nodeCount()), -1);
    auto vertex = [&](int n) {
        if (vertexOfNode[sz(n)] < 0) {
            vertexOfNode[sz(n)] = static_cast<std::int32_t>(out.vertices.size());
            out.vertices.push_back(nodePosition(n).cast<float>());
            out.vertexNode.push_back(n);
        }
        return static_cast<std::uint32_t>(vertexOfNode[sz(n)]);
    };
    const auto cc = cellCounts();
    // Local node quads per face, ordered counter-clockwise seen from outside.
    static constexpr int kFaceQuads[6][4] = {
        {0, 4, 6, 2},  // -x
        {1, 3, 7, 5},  // +x
        {0, 1, 5, 4},  // -y
        {2, 6, 7, 3},  // +y
        {0, 2, 3, 1},  // -z
        {4, 5, 7, 6},  // +z
    };
    for (int k = 0; k < cc[2]; ++k) {
        for (int j = 0; j < cc[1]; ++j) {
            for (int i = 0; i < cc[0]; ++i) {
                const int c = cell(i, j, k);
                if (!cellActive(c)) continue;
                const std::array<int, 3> ijk{i, j, k};
                const auto nodes = cellNodes(c);
                for (int f = 0; f < 6; ++f) {
                    const int axis = f / 2;
                    const int step = (f % 2 == 1) ? 1 : -1;
                    std::array<int, 3> nb = ijk;
                    nb[sz(axis)] += step;
                    const bool outside = nb[sz(axis)] < 0 || nb[sz(axis)] >= cc[sz(axis)];
                    if (!outside && cellActive(cell(nb[0], nb[1], nb[2]))) continue;
                    const auto& q = kFaceQuads[f];
                    const std::uint32_t v0 = vertex(nodes[sz(q[0])]);
                    const std::uint32_t v1 = vertex(nodes[sz(q[1])]);
                    const std::uint32_t v2 = vertex(nodes[sz(q[2])]);
                    const std::uint32_t v3 = vertex(nodes[sz(q[3])]);
                    out.triangles.push_back({v0, v1, v2});
                    out.triangles.push_back({v0, v2, v3});
                }
            }
        }
    }
    return out;
}

}  // namespace palp::fem
