#pragma once
/// @file
/// Isotropic elastic material (linear, or neo-Hookean at large strain) and Rayleigh damping for
/// palp's hexahedral FEM.

#include <Eigen/Core>

namespace palp::fem {

/// The constitutive law of an ElasticMaterial.
enum class MaterialLaw {
    /// Small-strain linear elasticity (every solver).
    linear,
    /// Compressible neo-Hookean at large strain with the same small-strain E and nu, run by
    /// total Lagrangian explicit dynamics (palp/fem/tled.h): the whole-mesh ExplicitSolver only;
    /// the implicit solver and the asynchronous regions refuse it.
    neoHookean,
};

/// Isotropic elastic material with density and Rayleigh damping `C = alpha M + beta K`.
struct ElasticMaterial {
    double youngsModulus = 5.0e3;  ///< E, pascals, [1, 1e12]; a per-element field may scale it
    double poissonRatio = 0.45;    ///< nu, dimensionless, in (-1, 0.5)
    double density = 1.0e3;        ///< rho, kg/m^3, [1, 1e5]
    double dampingAlpha = 0.0;     ///< mass-proportional Rayleigh coefficient, 1/s, [0, 1e4]
    double dampingBeta = 0.0;      ///< stiffness-proportional Rayleigh coefficient, s, [0, 1]
    MaterialLaw law = MaterialLaw::linear;  ///< constitutive law

    /// Lame's first parameter lambda, pascals.
    double lambda() const;
    /// Shear modulus mu, pascals.
    double mu() const;
    /// Dilatational (P-)wave speed `c_d = sqrt(E (1-nu) / (rho (1+nu) (1-2nu)))`, m/s.
    double dilatationalWaveSpeed() const;
};

/// Throws palp::ValueError naming the field (`material youngsModulus: expected a value in [1,
/// 1e+12] Pa, found 1e+300`) when @p material is outside palp/base/bounds.h's ranges:
/// youngsModulus kYoungsModulus, poissonRatio kPoissonRatio, density kDensity, dampingAlpha
/// kMassDamping, dampingBeta kStiffnessDamping (all finite).
/// @throw palp::ValueError
void validate(const ElasticMaterial& material);

/// 6x6 isotropic elasticity matrix (Voigt order xx, yy, zz, xy, yz, zx; engineering shear
/// strains), pascals.
Eigen::Matrix<double, 6, 6> elasticityMatrix(double youngsModulus, double poissonRatio);

}  // namespace palp::fem
