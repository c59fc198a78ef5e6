#pragma once
/// @file
/// Isotropic linear elastic material and Rayleigh damping for palp's hexahedral FEM.

#include <Eigen/Core>

namespace palp::fem {

/// Isotropic linear elastic material with density and Rayleigh damping `C = alpha M + beta K`.
struct ElasticMaterial {
    double youngsModulus = 5.0e3;  ///< E, pascals (> 0); a per-element field may scale it
    double poissonRatio = 0.45;    ///< nu, dimensionless, in (-1, 0.5)
    double density = 1.0e3;        ///< rho, kg/m^3 (> 0)
    double dampingAlpha = 0.0;     ///< mass-proportional Rayleigh coefficient, 1/s (>= 0)
    double dampingBeta = 0.0;      ///< stiffness-proportional Rayleigh coefficient, s (>= 0)

    /// Lame's first parameter lambda, pascals.
    double lambda() const;
    /// Shear modulus mu, pascals.
    double mu() const;
    /// Dilatational (P-)wave speed `c_d = sqrt(E (1-nu) / (rho (1+nu) (1-2nu)))`, m/s.
    double dilatationalWaveSpeed() const;
};

/// Throws palp::ValueError naming the field when @p material is outside the accepted ranges:
/// nu in (-1, 0.5), E > 0, density > 0, damping coefficients >= 0, all finite.
/// @throw palp::ValueError
void validate(const ElasticMaterial& material);

/// 6x6 isotropic elasticity matrix (Voigt order xx, yy, zz, xy, yz, zx; engineering shear
/// strains), pascals.
Eigen::Matrix<double, 6, 6> elasticityMatrix(double youngsModulus, double poissonRatio);

}  // namespace palp::fem
