#include "palp/fem/embedded_mesh.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <string>
#include <utility>

#include "palp/base/error.h"
#include "palp/base/validate.h"

namespace palp::fem {

namespace {

std::string point(const Eigen::Vector3d& p) {
    // Appended piece by piece: GCC 12 warns (-Wrestrict, a false positive) on "(" + string.
    std::string s("(");
    s += formatValue(p.x());
    s += ", ";
    s += formatValue(p.y());
    s += ", ";
    s += formatValue(p.z());
    s += ")";
    return s;
}

/// Squared distance, in element edges, from lattice point @p q to cell @p ijk ([i, i + 1] per
/// axis).
double cellDistanceSquared(const Eigen::Vector3d& q, const std::array<int, 3>& ijk) {
    double d2 = 0;
    for (int a = 0; a < 3; ++a) {
        const double lo = ijk[static_cast<std::size_t>(a)];
        const double d = q[a] - std::clamp(q[a], lo, lo + 1.0);
        d2 += d * d;
    }
    return d2;
}

}  // namespace

EmbeddedMesh::EmbeddedMesh(const FemModel& model, const TriangleMesh& rest)
    : EmbeddedMesh(model.mesh(), rest) {}

EmbeddedMesh::EmbeddedMesh(const HexMesh& mesh, const TriangleMesh& rest) : mRestMesh(rest) {
    if (mesh.elementCount() == 0) {
        throw ValueError("embedded mesh: expected a hex mesh with elements, found an empty one");
    }
    if (rest.positions.size() % 3 != 0) {
        throwExpected("embedded mesh positions", "a multiple of 3 floats (x, y, z per vertex)",
                      std::to_string(rest.positions.size()));
    }
    if (rest.positions.empty()) {
        throw ValueError("embedded mesh: expected at least one vertex, found none");
    }
    if (rest.indices.size() % 3 != 0) {
        throwExpected("embedded mesh triangle indices", "a multiple of 3",
                      std::to_string(rest.indices.size()));
    }
    const std::size_t nv = rest.vertexCount();
    for (std::size_t i = 0; i < rest.indices.size(); ++i) {
        if (rest.indices[i] >= nv) {
            throwExpected("embedded mesh triangle " + std::to_string(i / 3) + " index",
                          "a vertex index below " + std::to_string(nv),
                          std::to_string(rest.indices[i]));
        }
    }

    const double h = mesh.edge();
    const Eigen::Vector3d& origin = mesh.origin();
    const std::array<int, 3> cells = mesh.cellCounts();
    mDofCount = mesh.dofCount();
    mRest.resize(nv);
    mLocal.resize(nv);
    mCell.resize(nv);
    mDof.resize(nv);
    mWeight.resize(nv);
    std::vector<int> used;
    for (std::size_t v = 0; v < nv; ++v) {
        const Eigen::Vector3d x(rest.positions[3 * v], rest.positions[3 * v + 1],
                                rest.positions[3 * v + 2]);
        const std::string name = "embedded mesh vertex " + std::to_string(v);
        if (!x.allFinite()) throwExpected(name, "finite coordinates (m)", point(x));
        const Eigen::Vector3d q = (x - origin) / h;  // lattice coordinates, element edges
        const auto refuseFar = [&] {
            throwExpected(name + " at " + point(x) + " m",
                          "a position within one element edge (" + formatValue(h) +
                              " m) of an active cell of the hex mesh",
                          "none");
        };
        std::array<int, 3> lo{}, hi{}, natural{};
        for (int a = 0; a < 3; ++a) {
            const auto s = static_cast<std::size_t>(a);
            // Cells within one edge of q: [floor(q) - 2, floor(q) + 1] covers them all.
            if (!(q[a] >= -2.0 && q[a] <= cells[s] + 2.0)) refuseFar();
            const int f = static_cast<int>(std::floor(q[a]));
            lo[s] = std::max(0, f - 2);
            hi[s] = std::min(cells[s] - 1, f + 1);
            natural[s] = std::clamp(f, 0, cells[s] - 1);
        }
        // The cell that contains q first (the common case), then the nearest active one, ties
        // to the lowest cell index.
        int best = -1;
        std::array<int, 3> bestIjk{};
        double bestD2 = std::numeric_limits<double>::infinity();
        const int naturalCell = mesh.cell(natural[0], natural[1], natural[2]);
        if (mesh.cellActive(naturalCell) && cellDistanceSquared(q, natural) == 0.0) {
            best = naturalCell;
            bestIjk = natural;
            bestD2 = 0.0;
        } else {
            for (int k = lo[2]; k <= hi[2]; ++k) {
                for (int j = lo[1]; j <= hi[1]; ++j) {
                    for (int i = lo[0]; i <= hi[0]; ++i) {
                        const int c = mesh.cell(i, j, k);
                        if (!mesh.cellActive(c)) continue;
                        const double d2 = cellDistanceSquared(q, {i, j, k});
                        if (d2 < bestD2) {
                            best = c;
                            bestIjk = {i, j, k};
                            bestD2 = d2;
                        }
                    }
                }
            }
        }
        if (best < 0 || bestD2 > 1.0) refuseFar();
        const double d = std::sqrt(bestD2);
        if (d > kInsideTolerance) {
            ++mClampedCount;
            mMaxClampDistance = std::max(mMaxClampDistance, d * h);
        }
        Eigen::Vector3d xi;
        for (int a = 0; a < 3; ++a) {
            xi[a] = std::clamp(q[a] - bestIjk[static_cast<std::size_t>(a)], 0.0, 1.0);
        }
        const std::array<int, 8> nodes = mesh.cellNodes(best);
        std::array<double, 8> w{};
        std::array<std::int32_t, 8> dof{};
        for (std::size_t a = 0; a < 8; ++a) {
            w[a] = ((a & 1) ? xi.x() : 1.0 - xi.x()) * ((a & 2) ? xi.y() : 1.0 - xi.y()) *
                   ((a & 4) ? xi.z() : 1.0 - xi.z());
            dof[a] = 3 * nodes[a];
            used.push_back(nodes[a]);
        }
        mRest[v] = x;
        mLocal[v] = xi;
        mCell[v] = best;
        mDof[v] = dof;
        mWeight[v] = w;
    }
    std::sort(used.begin(), used.end());
    used.erase(std::unique(used.begin(), used.end()), used.end());
    mNodes = std::move(used);
}

std::array<double, 8> EmbeddedMesh::weights(std::size_t v) const noexcept { return mWeight[v]; }

template <class T>
bool EmbeddedMesh::updateImpl(const Eigen::VectorXd& u, std::span<T> positions) const noexcept {
    const std::size_t nv = mCell.size();
    if (u.size() != mDofCount || positions.size() != 3 * nv) return false;
    const double* ud = u.data();
    for (std::size_t v = 0; v < nv; ++v) {
        const std::array<std::int32_t, 8>& dof = mDof[v];
        const std::array<double, 8>& w = mWeight[v];
        double x = mRest[v].x(), y = mRest[v].y(), z = mRest[v].z();
        for (std::size_t a = 0; a < 8; ++a) {
            const double* n = ud + dof[a];
            x += w[a] * n[0];
            y += w[a] * n[1];
            z += w[a] * n[2];
        }
        positions[3 * v] = static_cast<T>(x);
        positions[3 * v + 1] = static_cast<T>(y);
        positions[3 * v + 2] = static_cast<T>(z);
    }
    return true;
}

bool EmbeddedMesh::update(const Eigen::VectorXd& u, std::span<float> positions) const noexcept {
    return updateImpl(u, positions);
}

bool EmbeddedMesh::update(const Eigen::VectorXd& u, std::span<double> positions) const noexcept {
    return updateImpl(u, positions);
}

}  // namespace palp::fem
