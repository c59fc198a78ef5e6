#include "palp/fem/components.h"

#include <Eigen/Core>
#include <algorithm>
#include <limits>
#include <numeric>
#include <sstream>
#include <string>

#include "index_cast.h"
#include "palp/base/error.h"
#include "palp/base/validate.h"

namespace palp::fem {

namespace {

/// Whether the lattice points @p points (integer node coordinates) include three not on one
/// line: exact in integers.
bool spansPlane(const std::vector<std::array<int, 3>>& points) {
    if (points.size() < 3) return false;
    const auto& p0 = points[0];
    const std::array<long, 3> none{0, 0, 0};
    std::array<long, 3> d1 = none;
    bool haveD1 = false;
    for (const auto& p : points) {
        const std::array<long, 3> d{p[0] - p0[0], p[1] - p0[1], p[2] - p0[2]};
        if (!haveD1) {
            if (d != none) {
                d1 = d;
                haveD1 = true;
            }
            continue;
        }
        const long cx = d1[1] * d[2] - d1[2] * d[1];
        const long cy = d1[2] * d[0] - d1[0] * d[2];
        const long cz = d1[0] * d[1] - d1[1] * d[0];
        if (cx != 0 || cy != 0 || cz != 0) return true;
    }
    return false;
}

std::vector<std::uint8_t> fixedFlags(const HexMesh& mesh, const std::vector<int>& fixedNodes) {
    std::vector<std::uint8_t> fixed(sz(mesh.nodeCount()), 0);
    for (const int n : fixedNodes) {
        if (n < 0 || n >= mesh.nodeCount()) {
            throwExpected("deformable fixed node",
                          "a node of the lattice (0.." + std::to_string(mesh.nodeCount() - 1) + ")",
                          std::to_string(n));
        }
        fixed[sz(n)] = 1;
    }
    return fixed;
}

int roundUpTo(int count, int multiple) { return (count + multiple - 1) / multiple * multiple; }

}  // namespace

std::vector<BodyPiece> bodyPieces(const HexMesh& mesh, const std::vector<std::uint8_t>& fixedNode,
                                  std::vector<int>* cellPiece) {
    if (fixedNode.size() != sz(mesh.nodeCount())) {
        throwExpected("body pieces fixed-node flags", std::to_string(mesh.nodeCount()) + " values",
                      std::to_string(fixedNode.size()));
    }
    const auto cc = mesh.cellCounts();
    const int cells = mesh.cellCount();
    std::vector<int> label(sz(cells), -1);
    std::vector<int> stack;
    std::vector<BodyPiece> pieces;
    std::vector<std::vector<std::array<int, 3>>> fixedPoints;
    std::vector<std::uint8_t> seenNode(sz(mesh.nodeCount()), 0);
    std::vector<int> touched;
    const std::array<int, 3> stride{1, cc[0], cc[0] * cc[1]};
    for (int seed = 0; seed < cells; ++seed) {
        if (!mesh.cellActive(seed) || label[sz(seed)] >= 0) continue;
        const int id = static_cast<int>(pieces.size());
        BodyPiece piece;
        piece.lo = Eigen::Vector3d::Constant(std::numeric_limits<double>::infinity());
        piece.hi = -piece.lo;
        std::vector<std::array<int, 3>> points;
        label[sz(seed)] = id;
        stack.push_back(seed);
        while (!stack.empty()) {
            const int c = stack.back();
            stack.pop_back();
            ++piece.cells;
            const std::array<int, 3> ijk{c % cc[0], (c / cc[0]) % cc[1], c / (cc[0] * cc[1])};
            for (int a = 0; a < 3; ++a) {
                const double lo = mesh.origin()[a] + ijk[sz(a)] * mesh.edge();
                piece.lo[a] = std::min(piece.lo[a], lo);
                piece.hi[a] = std::max(piece.hi[a], lo + mesh.edge());
            }
            for (const int n : mesh.cellNodes(c)) {
                if (seenNode[sz(n)]) continue;
                seenNode[sz(n)] = 1;
                touched.push_back(n);
                if (!fixedNode[sz(n)]) continue;
                ++piece.fixedNodes;
                // Three points not on one line decide; more only cost memory.
                if (points.size() < 64) points.push_back(mesh.nodeCoords(n));
            }
            for (int a = 0; a < 3; ++a) {
                for (int d = -1; d <= 1; d += 2) {
                    const int t = ijk[sz(a)] + d;
                    if (t < 0 || t >= cc[sz(a)]) continue;
                    const int m = c + d * stride[sz(a)];
                    if (mesh.cellActive(m) && label[sz(m)] < 0) {
                        label[sz(m)] = id;
                        stack.push_back(m);
                    }
                }
            }
        }
        // A node shared with another piece (an edge, a corner) counts for both.
        for (const int n : touched) seenNode[sz(n)] = 0;
        touched.clear();
        piece.anchored = spansPlane(points);
        if (!piece.anchored && piece.fixedNodes >= 3 && points.size() == 64) {
            // The first 64 were collinear: look at all of them (rare: a long edge of bone).
            points.clear();
            for (int c = 0; c < cells; ++c) {
                if (label[sz(c)] != id) continue;
                for (const int n : mesh.cellNodes(c))
                    if (fixedNode[sz(n)]) points.push_back(mesh.nodeCoords(n));
            }
            piece.anchored = spansPlane(points);
        }
        pieces.push_back(piece);
    }
    // Largest first (ties: first found first), labels renumbered to match.
    std::vector<int> order(pieces.size());
    std::iota(order.begin(), order.end(), 0);
    std::stable_sort(order.begin(), order.end(),
                     [&](int a, int b) { return pieces[sz(a)].cells > pieces[sz(b)].cells; });
    std::vector<int> rank(pieces.size());
    std::vector<BodyPiece> sorted;
    sorted.reserve(pieces.size());
    for (std::size_t r = 0; r < order.size(); ++r) {
        rank[sz(order[r])] = static_cast<int>(r);
        sorted.push_back(pieces[sz(order[r])]);
    }
    if (cellPiece) {
        for (int& l : label)
            if (l >= 0) l = rank[sz(l)];
        *cellPiece = std::move(label);
    }
    return sorted;
}

int AnchoredBody::renumber(int n, const HexMesh& given) const noexcept {
    const auto ijk = given.nodeCoords(n);
    const auto& counts = mesh.nodeCounts();
    std::array<int, 3> local{};
    for (int a = 0; a < 3; ++a) {
        local[sz(a)] = ijk[sz(a)] - offset[sz(a)];
        if (local[sz(a)] < 0 || local[sz(a)] >= counts[sz(a)]) return -1;
    }
    return mesh.node(local[0], local[1], local[2]);
}

void requireAnchored(const HexMesh& mesh, const std::vector<int>& fixedNodes) {
    const std::vector<BodyPiece> pieces = bodyPieces(mesh, fixedFlags(mesh, fixedNodes));
    for (std::size_t i = 0; i < pieces.size(); ++i) {
        const BodyPiece& p = pieces[i];
        if (p.anchored) continue;
        std::ostringstream s;
        s << "deformable supports: expected every piece of the body held by three fixed nodes "
             "not on one line, found piece "
          << i + 1 << " of " << pieces.size() << " (" << p.cells << " cells, " << p.fixedNodes
          << " fixed nodes, box " << (1e3 * p.lo).transpose() << " - " << (1e3 * p.hi).transpose()
          << " mm) free to move as a rigid body";
        throw ValueError(s.str());
    }
}

AnchoredBody anchorBody(const HexMesh& mesh, const std::vector<int>& fixedNodes) {
    const std::vector<std::uint8_t> fixed = fixedFlags(mesh, fixedNodes);
    std::vector<int> cellPiece;
    const std::vector<BodyPiece> pieces = bodyPieces(mesh, fixed, &cellPiece);
    AnchoredBody out;
    for (const BodyPiece& p : pieces) {
        if (p.anchored) {
            out.kept.push_back(p);
        } else {
            out.dropped.push_back(p);
            out.droppedCells += p.cells;
        }
    }
    if (out.kept.empty()) {
        std::ostringstream s;
        s << "deformable supports: expected a piece of tissue held by three fixed nodes not on "
             "one line (bone under it or a support face), found "
          << pieces.size() << (pieces.size() == 1 ? " piece" : " pieces") << " and none held";
        if (!pieces.empty()) {
            s << " (largest: " << pieces[0].cells << " cells, " << pieces[0].fixedNodes
              << " fixed nodes)";
        }
        throw ValueError(s.str());
    }
    // The box of the kept cells, in lattice cells.
    const auto cc = mesh.cellCounts();
    std::array<int, 3> lo{cc[0], cc[1], cc[2]}, hi{-1, -1, -1};
    for (int c = 0; c < mesh.cellCount(); ++c) {
        const int p = cellPiece[sz(c)];
        if (p < 0 || !pieces[sz(p)].anchored) continue;
        const std::array<int, 3> ijk{c % cc[0], (c / cc[0]) % cc[1], c / (cc[0] * cc[1])};
        for (int a = 0; a < 3; ++a) {
            lo[sz(a)] = std::min(lo[sz(a)], ijk[sz(a)]);
            hi[sz(a)] = std::max(hi[sz(a)], ijk[sz(a)]);
        }
    }
    std::array<int, 3> counts{};
    for (int a = 0; a < 3; ++a) counts[sz(a)] = roundUpTo(hi[sz(a)] - lo[sz(a)] + 1, 4);
    std::vector<double> youngs(sz(counts[0]) * sz(counts[1]) * sz(counts[2]), 0.0);
    for (int c = 0; c < mesh.cellCount(); ++c) {
        const int p = cellPiece[sz(c)];
        if (p < 0 || !pieces[sz(p)].anchored) continue;
        const int i = c % cc[0] - lo[0], j = (c / cc[0]) % cc[1] - lo[1],
                  k = c / (cc[0] * cc[1]) - lo[2];
        youngs[sz(i + counts[0] * (j + counts[1] * k))] = mesh.cellYoungs()[sz(c)];
    }
    const Eigen::Vector3d origin =
        mesh.origin() + mesh.edge() * Eigen::Vector3d(lo[0], lo[1], lo[2]);
    out.offset = lo;
    out.mesh = HexMesh::fromCells({counts[0] + 1, counts[1] + 1, counts[2] + 1}, mesh.edge(),
                                  origin, std::move(youngs));
    for (const int n : fixedNodes) {
        const int m = out.renumber(n, mesh);
        if (m >= 0 && out.mesh.nodeActive()[sz(m)]) out.fixedNodes.push_back(m);
    }
    std::sort(out.fixedNodes.begin(), out.fixedNodes.end());
    out.fixedNodes.erase(std::unique(out.fixedNodes.begin(), out.fixedNodes.end()),
                         out.fixedNodes.end());
    return out;
}

}  // namespace palp::fem
