// DeformableBody's map between the rest and the current configuration (deformable.h): the
// trilinear interpolation of the nodal displacements on the hex lattice, which inside an active
// element is the FEM's own displacement field.
#include <algorithm>
#include <cmath>

#include "palp/haptics/deformable.h"

namespace palp::haptics {

namespace {
constexpr int kMaxMapIterations = 12;
constexpr double kMapTolerance = 1e-9;  // m
}  // namespace

Eigen::Vector3d DeformableBody::nodeDisplacement(int n) const noexcept {
    if (mRegions) {
        // Nodes the regions do not track on the servo thread (secondary, unwatched) read NaN:
        // they count as undisplaced.
        const Eigen::Vector3d u = mRegions->nodeDisplacement(n);
        return u.allFinite() ? u : Eigen::Vector3d::Zero().eval();
    }
    return mSolver->displacement().segment<3>(3 * n);
}

Eigen::Vector3d DeformableBody::displacementAtRest(const Eigen::Vector3d& rest) const noexcept {
    if (!rest.allFinite()) return Eigen::Vector3d::Zero();
    const fem::HexMesh& mesh = mModel->model().mesh();
    const std::array<int, 3>& counts = mesh.nodeCounts();
    const Eigen::Vector3d g = (rest - mesh.origin()) / mesh.edge();
    std::array<int, 3> c{};
    std::array<double, 3> f{};
    for (std::size_t a = 0; a < 3; ++a) {
        // Outside the lattice: the nearest lattice point's displacement.
        const double cells = counts[a] - 1;
        const double x = std::clamp(g[static_cast<Eigen::Index>(a)], 0.0, cells);
        c[a] = std::min(static_cast<int>(x), counts[a] - 2);
        f[a] = x - c[a];
    }
    Eigen::Vector3d u = Eigen::Vector3d::Zero();
    for (int corner = 0; corner < 8; ++corner) {
        const int i = corner & 1, j = (corner >> 1) & 1, k = (corner >> 2) & 1;
        const double w = (i ? f[0] : 1 - f[0]) * (j ? f[1] : 1 - f[1]) * (k ? f[2] : 1 - f[2]);
        if (w == 0) continue;
        u += w * nodeDisplacement(mesh.node(c[0] + i, c[1] + j, c[2] + k));
    }
    return u;
}

Eigen::Vector3d DeformableBody::currentFromRest(const Eigen::Vector3d& rest) const noexcept {
    return rest + displacementAtRest(rest);
}

Eigen::Vector3d DeformableBody::restFromCurrent(const Eigen::Vector3d& current) const noexcept {
    if (!current.allFinite()) return current;
    // x = X + u(X): X <- x - u(X), a contraction while |grad u| < 1 (no element turned
    // inside out); from X = x - u(x), a few iterations reach a micrometre.
    Eigen::Vector3d rest = current - displacementAtRest(current);
    for (int it = 0; it < kMaxMapIterations; ++it) {
        const Eigen::Vector3d next = current - displacementAtRest(rest);
        const double change = (next - rest).norm();
        rest = next;
        if (!(change > kMapTolerance)) break;
    }
    return rest;
}

}  // namespace palp::haptics
