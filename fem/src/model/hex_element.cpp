#include "palp/fem/hex_element.h"

#include <cmath>

#include "palp/fem/material.h"

namespace palp::fem {

Eigen::Matrix<double, 6, 24> hexStrainDisplacement(double edge, double xi, double eta,
                                                   double zeta) {
    Eigen::Matrix<double, 6, 24> b = Eigen::Matrix<double, 6, 24>::Zero();
    // d(xi)/dx = 2 / h on a cube.
    const double j = 2.0 / edge;
    for (int a = 0; a < 8; ++a) {
        const double sx = (a & 1) ? 1.0 : -1.0;
        const double sy = (a & 2) ? 1.0 : -1.0;
        const double sz = (a & 4) ? 1.0 : -1.0;
        const double dx = 0.125 * sx * (1.0 + sy * eta) * (1.0 + sz * zeta) * j;
        const double dy = 0.125 * sy * (1.0 + sx * xi) * (1.0 + sz * zeta) * j;
        const double dz = 0.125 * sz * (1.0 + sx * xi) * (1.0 + sy * eta) * j;
        const int c = 3 * a;
        b(0, c) = dx;
        b(1, c + 1) = dy;
        b(2, c + 2) = dz;
        b(3, c) = dy;
        b(3, c + 1) = dx;
        b(4, c + 1) = dz;
        b(4, c + 2) = dy;
        b(5, c) = dz;
        b(5, c + 2) = dx;
    }
    return b;
}

Eigen::Matrix<double, 24, 24> hexStiffness(double edge, double youngsModulus, double poissonRatio) {
    const Eigen::Matrix<double, 6, 6> c = elasticityMatrix(youngsModulus, poissonRatio);
    const double g = 1.0 / std::sqrt(3.0);
    // Gauss weight 1 per point; dV = (h/2)^3 dxi deta dzeta.
    const double detJ = edge * edge * edge / 8.0;
    Eigen::Matrix<double, 24, 24> k = Eigen::Matrix<double, 24, 24>::Zero();
    for (int p = 0; p < 8; ++p) {
        const double xi = (p & 1) ? g : -g;
        const double eta = (p & 2) ? g : -g;
        const double zeta = (p & 4) ? g : -g;
        const Eigen::Matrix<double, 6, 24> b = hexStrainDisplacement(edge, xi, eta, zeta);
        k.noalias() += detJ * (b.transpose() * c * b);
    }
    // Symmetrise away rounding so that LDLT and energy identities hold to machine precision.
    return 0.5 * (k + k.transpose());
}

}  // namespace palp::fem
