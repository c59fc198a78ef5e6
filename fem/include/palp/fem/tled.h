#pragma once
/// @file
/// Total Lagrangian explicit dynamics (TLED; Miller, Joldes, Lance, Wittek 2007) for palp's
/// hexahedra: the compressible neo-Hookean law, the internal nodal forces of a displacement
/// evaluated with shape-function derivatives precomputed on the reference cube, one-point
/// integration with Flanagan-Belytschko hourglass control (Joldes, Wittek, Miller 2008) or full
/// 2x2x2 Gauss integration, and the stable step of the current state. docs/algorithms.md,
/// "Large strain: TLED", has the equations.

#include <Eigen/Core>
#include <array>
#include <span>

#include "palp/fem/fem_model.h"

namespace palp::fem {

/// The compressible neo-Hookean law `W = C10 (I1bar - 3) + (J - 1)^2 / D1`, `C10 = mu / 2`,
/// `D1 = 2 / K` (CalculiX's *HYPERELASTIC, NEO HOOKE; NiftySim's), with `I1bar = J^(-2/3) I1`.
/// At small strain it is the linear material of the same E and nu.
struct NeoHookean {
    double mu = 0.0;    ///< shear modulus, Pa: E / (2 (1 + nu))
    double bulk = 0.0;  ///< bulk modulus K, Pa: E / (3 (1 - 2 nu))

    /// The law with the small-strain moduli of Young's modulus @p youngsModulus (Pa) and Poisson
    /// ratio @p poissonRatio.
    static NeoHookean fromYoungs(double youngsModulus, double poissonRatio) noexcept;
    /// CalculiX's C10 = mu / 2, Pa.
    double c10() const { return 0.5 * mu; }
    /// CalculiX's D1 = 2 / K, 1/Pa.
    double d1() const { return 2.0 / bulk; }

    /// Strain energy density W at the deformation gradient @p f, J/m^3 (reference volume).
    double energy(const Eigen::Matrix3d& f) const noexcept;
    /// Second Piola-Kirchhoff stress `S = mu J^(-2/3) (I - I1 / 3 C^-1) + K J (J - 1) C^-1`
    /// at @p f, Pa (C = F^T F).
    Eigen::Matrix3d secondPiola(const Eigen::Matrix3d& f) const noexcept;
    /// First Piola-Kirchhoff stress P = F S at @p f, Pa, evaluated as
    /// `mu J^(-2/3) F + (K (J - 1) - mu J^(-2/3) I1 / (3 J)) cof F` (the same tensor without
    /// inverting C).
    Eigen::Matrix3d firstPiola(const Eigen::Matrix3d& f) const noexcept;
};

/// How the TLED element integrates its internal force.
enum class TledIntegration {
    /// One point at the element centre (the uniform-strain hexahedron) with Flanagan-Belytschko
    /// stiffness hourglass control: the fast path.
    onePointHourglass,
    /// Full 2x2x2 Gauss integration (CalculiX's C3D8): the reference.
    gauss2x2x2,
};

/// Options of the TLED element.
struct TledOptions {
    TledIntegration integration = TledIntegration::onePointHourglass;
    /// Flanagan-Belytschko hourglass stiffness coefficient kappa, dimensionless, in [0, 1]: each
    /// of the 4 x 3 hourglass modes (unit nodal vectors) of a cell has stiffness
    /// `kappa (lambda + 2 mu) h` (N/m). The fully integrated linear cube has 0.07-0.18 on its
    /// modes at nu = 0.45. Used by onePointHourglass only.
    double hourglassKappa = 0.1;
};

/// The TLED internal force of a FemModel's mesh and per-cell modulus (the model's Poisson ratio,
/// the neo-Hookean law of each cell's E): everything precomputed at construction on the
/// reference cube (shape derivatives at the integration points, hourglass vectors), nothing
/// allocated after.
///
/// @par Threading  Immutable after construction: const methods may be called from many threads.
/// The model must outlive it.
class TledForces {
  public:
    /// @throw palp::ValueError for options out of range.
    explicit TledForces(const FemModel& model, const TledOptions& options = {});

    const TledOptions& options() const { return mOptions; }

    /// f += f_int(u): the internal nodal forces (newtons, #dofs) of the displacement @p u
    /// (metres, #dofs) over all active cells, one thread.
    /// @par Real-time  noexcept, allocation-free, bounded by the element count.
    void addInternalForces(const double* u, double* f) const noexcept;
    /// The same over cells with k in [kBegin, kEnd) only. @par Real-time
    void addInternalForcesSlab(const double* u, double* f, int kBegin, int kEnd) const noexcept;
    /// f = f_int(u) with TBB: slabs of even and then odd k in parallel (no write conflicts).
    void internalForcesParallel(const double* u, double* f) const;

    /// f += f_int(u) over the listed cells only (the primary region of the asynchronous regions):
    /// @p cellDofs holds `3 * node` of each cell's 8 nodes (HexMesh's corner order; cells of this
    /// model's mesh), @p cellE their Young's moduli (0: no force), the same length. With AVX2,
    /// four cells adjacent in a lattice row and listed one after the other go as one row group,
    /// the others four at a time from anywhere.
    /// @par Real-time  noexcept, allocation-free, O(#cells).
    void addCellForces(const double* u, double* f, std::span<const std::array<int, 8>> cellDofs,
                       std::span<const double> cellE) const noexcept;
    /// frequencyBound() over the listed cells only (as addCellForces()). @par Real-time
    double frequencyBoundCells(const double* u, std::span<const std::array<int, 8>> cellDofs,
                               std::span<const double> cellE) const noexcept;

    /// Strain energy of @p u (#dofs), joules: W at the integration points (plus the hourglass
    /// springs' energy for onePointHourglass). @par Real-time
    double strainEnergy(const double* u) const noexcept;

    /// Highest angular frequency (rad/s) of the undeformed lumped-mass TLED mesh (the largest
    /// element eigenvalue of M_e^-1 K_e of its small-strain stiffness; the linear model's bound
    /// for gauss2x2x2).
    double restFrequencyBound() const { return mOmegaRest; }
    /// The same bound in the state @p u (#dofs, metres): restFrequencyBound() times the square
    /// root of the largest ratio, over active cells, of the current to the undeformed
    /// dilatational stiffness (an upper bound of the neo-Hookean acoustic tensor at the cell
    /// centre, docs/algorithms.md). Compression stiffens the shear part and raises it.
    /// @par Real-time
    double frequencyBound(const double* u) const noexcept;
    /// The critical central-difference step (seconds) of frequency bound @p omega (rad/s) plus
    /// @p extraOmega2 (rad^2/s^2, a coupling spring) with the model's Rayleigh damping, as
    /// FemModel::criticalTimeStep(). @par Real-time
    double criticalTimeStep(double omega, double extraOmega2 = 0.0) const noexcept;

  private:
    /// The hourglass spring of each mode for E = 1 Pa and edge @p edge: kappa (K + 4/3 mu) h.
    double hourglassStiffness(double edge) const noexcept;
    /// The frequency bound of the largest cell stiffening @p worst (cellStiffening in tled.cpp).
    double boundFromStiffening(double worst) const noexcept;

    const FemModel& mModel;
    TledOptions mOptions;
    double mOmegaRest = 0.0;
    double mCellEMax = 0.0;
    NeoHookean mUnitLaw;  // the law for E = 1 Pa
    bool mAvx2 = false;   // the one-point kernel's AVX2+FMA path (palp/base/simd.h)
    // Shape-function derivatives dN_a/dX_J times h (dimensionless) at the 8 Gauss points:
    // [point][node][axis].
    double mGaussGrad[8][8][3] = {};
};

}  // namespace palp::fem
