#pragma once
// Shared problem set-ups for the FEM tests.

#include <algorithm>
#include <cmath>
#include <vector>

#include "palp/fem/constraints.h"
#include "palp/fem/fem_model.h"
#include "palp/fem/hex_mesh.h"

namespace palp::fem::test {

/// Soft tissue of the issue: E = 5 kPa, nu = 0.45, rho = 1000 kg/m^3.
inline ElasticMaterial softTissue(double alpha = 0.0, double beta = 0.0) {
    ElasticMaterial m;
    m.youngsModulus = 5.0e3;
    m.poissonRatio = 0.45;
    m.density = 1.0e3;
    m.dampingAlpha = alpha;
    m.dampingBeta = beta;
    return m;
}

/// The 13x13x13-node cube of edge 60 mm (h = 5 mm).
inline HexMesh cube13(double youngs = 5.0e3) {
    return HexMesh::box(Eigen::Vector3d::Constant(0.06), {13, 13, 13}, youngs);
}

/// Bottom face (z = 0) fully fixed.
inline Constraints bottomFixed(const HexMesh& mesh) {
    Constraints c(mesh.dofCount());
    c.fixNodes(mesh.faceNodes(BoxFace::zMin));
    return c;
}

/// Downward patch load of @p totalNewtons on the top-face nodes within the centre square of
/// half-width @p halfWidth metres.
inline Eigen::VectorXd topPatchLoad(const HexMesh& mesh, double totalNewtons, double halfWidth) {
    Eigen::VectorXd f = Eigen::VectorXd::Zero(mesh.dofCount());
    std::vector<int> patch;
    const auto& nc = mesh.nodeCounts();
    const Eigen::Vector3d centre =
        mesh.origin() + 0.5 * mesh.edge() * Eigen::Vector3d(nc[0] - 1, nc[1] - 1, 0);
    for (int n : mesh.faceNodes(BoxFace::zMax)) {
        const Eigen::Vector3d p = mesh.nodePosition(n);
        if (std::abs(p.x() - centre.x()) <= halfWidth + 1e-12 &&
            std::abs(p.y() - centre.y()) <= halfWidth + 1e-12) {
            patch.push_back(n);
        }
    }
    for (int n : patch) f[3 * n + 2] = -totalNewtons / static_cast<double>(patch.size());
    return f;
}

/// Largest magnitude of a force history, N.
inline double peak(const std::vector<double>& f) {
    double m = 0.0;
    for (double v : f) m = std::max(m, std::abs(v));
    return m;
}

/// Relative RMS error of @p f against the reference @p ref (same length).
inline double rmsError(const std::vector<double>& f, const std::vector<double>& ref) {
    double num = 0.0, den = 0.0;
    for (std::size_t k = 0; k < ref.size(); ++k) {
        num += (f[k] - ref[k]) * (f[k] - ref[k]);
        den += ref[k] * ref[k];
    }
    return std::sqrt(num / den);
}

}  // namespace palp::fem::test
