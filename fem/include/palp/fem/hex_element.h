#pragma once
/// @file
/// The 8-node trilinear hexahedron on a cube of edge h, integrated with 2x2x2 Gauss points.

#include <Eigen/Core>

namespace palp::fem {

/// Element stiffness `Ke = integral B^T C B dV` (24x24, N/m) of a cube of edge @p edge metres,
/// Young's modulus @p youngsModulus Pa, Poisson ratio @p poissonRatio, 2x2x2 Gauss points.
/// Dof order: local node a (lexicographic, x fastest) times 3 plus component.
Eigen::Matrix<double, 24, 24> hexStiffness(double edge, double youngsModulus, double poissonRatio);

/// Strain-displacement matrix B (6x24, 1/m; Voigt xx, yy, zz, xy, yz, zx with engineering
/// shear) at local coordinates (xi, eta, zeta) in [-1, 1]^3 of a cube of edge @p edge.
Eigen::Matrix<double, 6, 24> hexStrainDisplacement(double edge, double xi, double eta, double zeta);

}  // namespace palp::fem
