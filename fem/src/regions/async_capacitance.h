#pragma once
/// @file
/// GlobalSecondary: the quasi-static CHOLMOD secondary of AsyncRegions factorised ONCE for the
/// whole body, so that a contact change needs no assembly and no factorisation (issue 18).
///
/// The secondary of a layout solves `A_S u = b` with `A_S = I_S^T K I_S` (I_S: the coarse
/// interpolation with the rows of the primary nodes P removed). The whole body's Galerkin
/// matrix `A = I^T K I` (every free fine dof interpolated) differs from A_S only in the rows and
/// columns of J, the coarse dofs at the corners of the primary coarse cells: a fine node whose
/// interpolation reaches outside J is a secondary node and keeps its row. With the coarse dofs
/// that no secondary node uses (interior to the primary) decoupled on the diagonal,
///
///     M = A + E_J D E_J^T,   D = M_JJ - A_JJ (|J| x |J|, assembled locally per layout),
///
/// and by the capacitance (Woodbury) identity, with `Z = (A^-1)_JJ` and `H = (I + D Z)^-1`:
///
///     (M^-1)_JJ = Z H,     M^-1 E_J = A^-1 E_J H,     M^-1 b = y - A^-1 E_J H D y_J  (y = A^-1 b).
///
/// The Gamma rows and the border coupling `I_S^T K_SB` live in J, so the condensed and direct
/// responses need only Z; the watched responses need `(A^-1)_WJ`. Both come from one dense block
/// `W = (A^-1)_TT` over a zone T of coarse dofs that holds J for every contact node the contact
/// may slide to (and the watched nodes' coarse support): the factorisation orders T last
/// (CAMD with T as its last constraint set), so `W = L_TT^-T L_TT^-1` from the factor's last
/// block, computed once at set-up. A layout is then gathers and |J|^3 dense work (|J| ~ 50-300):
/// milliseconds. A whole-field solve (loads on secondary nodes, displacement(), a layout change)
/// costs two solves with the global factor instead of one with the layout's.
///
/// @par Threading  Built on the constructing thread. Afterwards the zone data (interpolation, A,
/// W, zone positions) is read-only and may be read by any thread (the layout builder); solve()
/// uses the factor's CHOLMOD workspace and is called only from the secondary's thread.

#include <Eigen/Core>
#include <Eigen/SparseCore>
#include <cstdint>
#include <memory>
#include <vector>

#include "regions/async_layout.h"
#include "regions/async_setup.h"

namespace palp::fem {

/// The whole body's secondary system, factorised once, and the zone block of its inverse.
class GlobalSecondary {
  public:
    /// Assembles `A = I^T K I` over every free coarse dof, orders the zone of @p zoneCoarseNodes
    /// (coarse node indices, coarseCounts order) last, factorises and inverts the zone block.
    /// @throw palp::ValueError for a failed factorisation (rigid-body motion left free).
    GlobalSecondary(const AsyncSetup& setup, const SparseMatrix& stiffness,
                    const std::vector<int>& zoneCoarseNodes);
    ~GlobalSecondary();
    GlobalSecondary(const GlobalSecondary&) = delete;
    GlobalSecondary& operator=(const GlobalSecondary&) = delete;

    /// Fine dofs x unknowns: trilinear interpolation of every free fine dof.
    const RowSparseMatrix& interpolation() const { return mInterp; }
    /// Same, column-major (column extraction per layout).
    const SparseMatrix& interpolationByColumn() const { return mInterpCol; }
    /// Unknown -> coarse dof.
    const std::vector<int>& unknownCoarseDof() const { return mUnknownCoarseDof; }
    /// Coarse dof -> unknown, or -1.
    int unknownOf(int coarseDof) const { return mUnknownOf[static_cast<std::size_t>(coarseDof)]; }
    /// Position of unknown @p u in the zone block W, or -1 outside the zone.
    int zonePosition(int u) const { return mZonePos[static_cast<std::size_t>(u)]; }
    /// Number of zone unknowns.
    int zoneSize() const { return static_cast<int>(mW.rows()); }
    /// `(A^-1)_TT`, zone positions.
    const Eigen::MatrixXd& zoneInverse() const { return mW; }
    /// The whole body's matrix A (unknowns x unknowns, both triangles).
    const SparseMatrix& matrix() const { return mA; }
    /// Wall time of the set-up's factorisation and zone inversion, seconds.
    double factoriseSeconds() const { return mFactoriseSeconds; }
    double zoneSeconds() const { return mZoneSeconds; }

    /// Prepares @p L's capacitance data (L.capJ, L.capZH, L.capHD) and its responses (direct
    /// Gamma and watched responses, the condensed G) from the zone block. @p primaryCoarseCells
    /// lists the primary coarse cells (coarse cell indices). @return false when J leaves the
    /// zone (the caller then assembles and factorises the layout the old way).
    bool prepareLayout(Layout& L, const std::vector<int>& primaryCoarseCells,
                       const SparseMatrix& stiffness) const;

    /// x = M^-1 rhs for @p L (see the file comment): two solves with the global factor.
    /// Secondary's thread only (CHOLMOD workspace). Allocation-free after the first call.
    /// @return false when CHOLMOD failed.
    bool solve(const Layout& L, const Eigen::VectorXd& rhs, Eigen::VectorXd& x) const noexcept;

    /// The part of @p L's field due to the period's loads @p loads (fine dofs, newtons; those
    /// on @p L's primary nodes dropped) from the zone block, without a solve: with b = I_S^T f
    /// on zone unknowns, `(M^-1 b)_T = W b - W_TJ H D (W b)_J` into L.loadZone and b into
    /// L.loadRhs; L.loaded tells whether any load was taken. Costs (#loaded unknowns + |J|)
    /// zone columns (~1 ms at 33^3 lod 2), against two solves with the factor for the whole
    /// field. @return false (L.loaded false) when a load interpolates from outside the zone.
    /// Secondary's thread only (work vectors). Allocation-free.
    bool loadResponse(Layout& L, const BorderPacket& loads) const noexcept;

    /// The field of @p L's last border (L.border) and loads (L.loaded) on the zone (zone
    /// positions) into @p out (zone size): |T| x |J| multiply-adds. Secondary's thread only.
    void zoneField(const Layout& L, Eigen::VectorXd& out) const noexcept;

    /// The field of @p L's last border (L.border) and loads (L.loaded) at fine dofs @p dofs
    /// (secondary nodes), from the zone block without a solve. @return false (nothing written)
    /// when one of them interpolates from outside the zone. Any thread that owns @p L's work
    /// state.
    bool borderFieldAt(const Layout& L, const std::vector<int>& dofs,
                       std::vector<double>& values) const;
    /// `I_dofs W(., J)` at fine dofs @p dofs for the unknowns @p capJ, factored into @p basis
    /// (interp_basis.h). @return false (basis cleared) when one of the dofs interpolates from
    /// outside the zone. Read-only, any thread.
    bool zoneRowsAt(const std::vector<int>& dofs, const std::vector<int>& capJ,
                    InterpBasis& basis) const;
    /// The response of @p L's field at fine dofs @p dofs (secondary nodes) to its border,
    /// `d x_dofs / d u_B = I_dofs W_(.,J) Q` (|dofs| x |border|), factored: @p basis =
    /// `I_dofs W_(.,J)` (|dofs| x |J|, itself factored, interp_basis.h) and @p q = Q (|J| x
    /// |border|; |J| may be 0). @return
    /// false (both empty) when one of them interpolates from outside the zone. Read-only, any
    /// thread.
    bool borderResponseAt(const Layout& L, const std::vector<int>& dofs, InterpBasis& basis,
                          Eigen::MatrixXd& q) const;

  private:
    struct Factor;
    bool solveA(const double* b, double* x) const noexcept;

    const AsyncSetup& mSetup;
    RowSparseMatrix mInterp;
    SparseMatrix mInterpCol;
    std::vector<int> mUnknownCoarseDof, mUnknownOf, mZonePos;
    SparseMatrix mA;
    Eigen::MatrixXd mW;
    std::unique_ptr<Factor> mFactor;
    mutable Eigen::VectorXd mY, mR;
    mutable Eigen::VectorXd mBz, mVj;         // loadResponse: b on the zone, H D (W b)_J
    mutable std::vector<int> mTouched;        // loadResponse: zone positions b touches
    mutable std::vector<std::uint8_t> mMark;  // loadResponse: per zone position, in mTouched
    double mFactoriseSeconds = 0.0, mZoneSeconds = 0.0;
};

}  // namespace palp::fem
