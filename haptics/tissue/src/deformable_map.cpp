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

namespace {

/// The proper rotation nearest @p m (its polar factor, from the SVD m = U S V^T: U V^T with the
/// smallest singular direction flipped should that reflect); the identity when @p m is not
/// finite or is degenerate.
Eigen::Matrix3d nearestRotation(const Eigen::Matrix3d& m) noexcept {
    if (!m.allFinite()) return Eigen::Matrix3d::Identity();
    const Eigen::JacobiSVD<Eigen::Matrix3d> svd(m, Eigen::ComputeFullU | Eigen::ComputeFullV);
    if (!(svd.singularValues()[1] > 0)) return Eigen::Matrix3d::Identity();
    Eigen::Matrix3d U = svd.matrixU();
    if ((U * svd.matrixV().transpose()).determinant() < 0) U.col(2) = -U.col(2);
    const Eigen::Matrix3d R = U * svd.matrixV().transpose();
    return R.allFinite() ? R : Eigen::Matrix3d::Identity().eval();
}

/// Surface vertex @p v's rotation from rest to now: the rotation that best takes its one-ring's
/// rest edges and its rest normal to the current ones (least squares, as-rigid-as-possible's
/// local step: the polar factor of sum e e_rest^T plus the normals' term, weighted by the
/// ring's mean squared edge length so that a flat ring's side is fixed by the normal).
Eigen::Matrix3d vertexRotation(const DeformableModel& model, const std::vector<float>& now,
                               std::size_t v) noexcept {
    const fem::SurfaceMesh& surface = model.surface();
    const auto rest = [&](std::size_t i) { return surface.vertices[i].cast<double>(); };
    const auto current = [&](std::size_t i) {
        return Eigen::Vector3d(now[3 * i], now[3 * i + 1], now[3 * i + 2]);
    };
    const Eigen::Vector3d r0 = rest(v), c0 = current(v);
    Eigen::Matrix3d cross = Eigen::Matrix3d::Zero();  // sum of current x rest^T
    Eigen::Vector3d nRest = Eigen::Vector3d::Zero(), nNow = Eigen::Vector3d::Zero();
    double edges2 = 0;
    int edges = 0;
    const std::vector<int>& start = model.triangleStart();
    const std::vector<int>& tris = model.vertexTriangles();
    for (int i = start[v]; i < start[v + 1]; ++i) {
        const auto& t =
            surface.triangles[static_cast<std::size_t>(tris[static_cast<std::size_t>(i)])];
        for (std::size_t k = 0; k < 3; ++k) {
            const std::size_t u = t[k];
            if (u == v) continue;
            const Eigen::Vector3d er = rest(u) - r0;
            cross += (current(u) - c0) * er.transpose();
            edges2 += er.squaredNorm();
            ++edges;
        }
        nRest += (rest(t[1]) - rest(t[0])).cross(rest(t[2]) - rest(t[0]));
        nNow += (current(t[1]) - current(t[0])).cross(current(t[2]) - current(t[0]));
    }
    const double lr = nRest.norm(), lc = nNow.norm();
    if (edges == 0 || !(lr > 0) || !(lc > 0)) return Eigen::Matrix3d::Identity();
    cross += (edges2 / edges) * (nNow / lc) * (nRest / lr).transpose();
    return nearestRotation(cross);
}

}  // namespace

Eigen::Matrix3d DeformableBody::anchorRotation() const noexcept {
    if (mAnchorTri < 0) return Eigen::Matrix3d::Identity();
    const auto& t = mModel->surface().triangles[static_cast<std::size_t>(mAnchorTri)];
    // The vertices' rotations blended with the anchor's barycentric weights (clamped to the
    // triangle), then the nearest rotation: continuous across the triangle's edges and
    // vertices, where a per-triangle frame jumped.
    std::array<double, 3> w{};
    double sum = 0;
    for (std::size_t k = 0; k < 3; ++k) {
        w[k] = std::isfinite(mAnchorBary[k]) ? std::max(mAnchorBary[k], 0.0) : 0.0;
        sum += w[k];
    }
    if (!(sum > 0)) w = {1.0 / 3, 1.0 / 3, 1.0 / 3};
    Eigen::Matrix3d blend = Eigen::Matrix3d::Zero();
    for (std::size_t k = 0; k < 3; ++k)
        if (w[k] > 0) blend += w[k] * vertexRotation(*mModel, mPositions, t[k]);
    return nearestRotation(blend);
}

}  // namespace palp::haptics
