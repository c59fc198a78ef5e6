// DeformableBody's map between the rest and the current configuration (deformable.h): the
// trilinear interpolation of the nodal displacements on the hex lattice, which inside an active
// element is the FEM's own displacement field.
#include <Eigen/Geometry>
#include <Eigen/LU>
#include <Eigen/SVD>
#include <algorithm>
#include <cmath>

#include "palp/haptics/tissue/deformable.h"

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

Eigen::Matrix3d DeformableBody::anchorRotation() const noexcept {
    if (mAnchorTri < 0) return Eigen::Matrix3d::Identity();
    const fem::SurfaceMesh& surface = mModel->surface();
    const auto& t = surface.triangles[static_cast<std::size_t>(mAnchorTri)];
    Eigen::Matrix3d rest, now;  // columns: edge 1, edge 2, unit normal
    Eigen::Vector3d r[3], c[3];
    for (std::size_t k = 0; k < 3; ++k) {
        const std::size_t v = t[k];
        r[k] = surface.vertices[v].cast<double>();
        c[k] = Eigen::Vector3d(mPositions[3 * v], mPositions[3 * v + 1], mPositions[3 * v + 2]);
    }
    rest.col(0) = r[1] - r[0];
    rest.col(1) = r[2] - r[0];
    now.col(0) = c[1] - c[0];
    now.col(1) = c[2] - c[0];
    const Eigen::Vector3d nr = rest.col(0).cross(rest.col(1)), nc = now.col(0).cross(now.col(1));
    const double lr = nr.norm(), lc = nc.norm();
    if (!(lr > 0) || !(lc > 0) || !std::isfinite(lr) || !std::isfinite(lc))
        return Eigen::Matrix3d::Identity();
    rest.col(2) = nr / lr;
    now.col(2) = nc / lc;
    // F rest = now; its polar factor (nearest rotation) from the SVD F = U S V^T: R = U V^T,
    // with the sign of the smallest singular direction flipped should F reflect (it cannot
    // for a triangle that keeps its orientation, but a crushed one could).
    const Eigen::Matrix3d F = now * rest.inverse();
    const Eigen::JacobiSVD<Eigen::Matrix3d> svd(F, Eigen::ComputeFullU | Eigen::ComputeFullV);
    Eigen::Matrix3d U = svd.matrixU();
    if ((U * svd.matrixV().transpose()).determinant() < 0) U.col(2) = -U.col(2);
    const Eigen::Matrix3d R = U * svd.matrixV().transpose();
    return R.allFinite() ? R : Eigen::Matrix3d::Identity().eval();
}

}  // namespace palp::haptics
