#pragma once
/// @file
/// FemModel: a hex mesh with its material, the unit element stiffness, lumped mass, the
/// matrix-free element-by-element stiffness operator and TBB-parallel sparse assembly.

#include <Eigen/Core>
#include <Eigen/SparseCore>
#include <array>
#include <vector>

#include "palp/fem/hex_mesh.h"
#include "palp/fem/material.h"

namespace palp::fem {

/// Sparse matrix type of assembled operators (3N x 3N, symmetric, full storage).
using SparseMatrix = Eigen::SparseMatrix<double, Eigen::ColMajor, int>;

/// A mesh plus material: everything the solvers need that does not depend on supports or loads.
/// The per-element Young's modulus comes from the mesh; `material.youngsModulus` is not used for
/// the stiffness (it is kept for export and wave-speed reference only).
///
/// @par Threading  Immutable after construction: const methods may be called from many threads.
class FemModel {
  public:
    /// Validates the material and the mesh (non-empty) and precomputes the unit element
    /// stiffness (E = 1 Pa) and the lumped mass. The mesh may hold several pieces: the supports
    /// must hold each (fem/components.h checks and resolves that).
    /// @throw palp::ValueError for bad material or an empty mesh.
    FemModel(HexMesh mesh, const ElasticMaterial& material);

    const HexMesh& mesh() const { return mMesh; }
    const ElasticMaterial& material() const { return mMaterial; }
    /// Number of degrees of freedom (3 per lattice node).
    int dofCount() const { return mMesh.dofCount(); }

    /// Element stiffness for E = 1 Pa (24x24, column-major, 64-byte aligned), N/m per Pa.
    const double* unitStiffness() const { return mUnitKe.data(); }
    /// Lumped mass per dof, kg (#dofs; 0 on inactive nodes): rho h^3 / 8 per node per element.
    const Eigen::VectorXd& lumpedMass() const { return mMass; }
    /// Total mass of the active elements, kg.
    double totalMass() const;

    /// f += K u, element by element over all active cells (matrix-free, one thread).
    /// @p u and @p f are #dofs long, metres and newtons.
    /// @par Real-time  noexcept, allocation-free, bounded by the element count.
    void addStiffnessTimes(const double* u, double* f) const noexcept;
    /// f += K u over the cells with k in [kBegin, kEnd) only (building block of the above).
    /// @par Real-time
    void addStiffnessTimesSlab(const double* u, double* f, int kBegin, int kEnd) const noexcept;
    /// f = K u with TBB: cell slabs of even and then odd k run in parallel (no write conflicts).
    void stiffnessTimesParallel(const double* u, double* f) const;

    /// K assembled in parallel (rows of nodes in parallel, gathered from adjacent elements),
    /// 3N x 3N, N/m. Rows and columns of inactive nodes are empty.
    SparseMatrix assembleStiffness() const;

    /// Upper bound on the highest angular frequency (rad/s) of the undamped lumped-mass system,
    /// from the largest element eigenvalue of M_e^-1 K_e (element eigenvalue inequality).
    double maxFrequencyBound() const { return mOmegaMax; }
    /// Largest stable explicit central-difference step, seconds, with Rayleigh damping:
    /// `dt = (2 / w) (sqrt(1 + xi^2) - xi)`, `xi = (alpha / w + beta w) / 2`, w =
    /// maxFrequencyBound.
    double criticalTimeStep() const;

    /// Strain energy `u^T K u / 2`, joules, of displacement @p u (#dofs).
    double strainEnergy(const Eigen::VectorXd& u) const;

  private:
    HexMesh mMesh;
    ElasticMaterial mMaterial;
    alignas(64) std::array<double, 576> mUnitKe{};
    Eigen::VectorXd mMass;
    double mOmegaMax = 0.0;
};

}  // namespace palp::fem
