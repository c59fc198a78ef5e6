#pragma once
/// @file
/// SecondaryRegion: the implicit secondary region of AsyncRegions (quasi-static, Newmark or
/// backward Euler in the Galerkin coarse space, by CHOLMOD or the shared PCG), its state in the
/// full coarse indexing and its counters.

#include <Eigen/Core>
#include <atomic>
#include <chrono>
#include <cstdint>

#include "regions/async_layout.h"
#include "regions/async_setup.h"

namespace palp::fem {

/// The secondary's solver state: the coarse field u_c (and, for the dynamic schemes, its
/// velocity and acceleration) carried across layouts, and the solve of one period.
/// @par Threading  Owned by the secondary's thread: the secondary thread in threaded mode, the
/// servo thread (at period boundaries, inside the secondary's task_arena) in synchronous mode.
/// It writes the secondary work state of the layouts it solves (Layout::x ..), never the
/// primary's. Only the counters are read from another thread (stats(): atomics, relaxed except
/// the solve and preparation counts, which are released after their values).
class SecondaryRegion {
  public:
    /// Zero coarse state. @p setup must outlive the region.
    explicit SecondaryRegion(const AsyncSetup& setup);

    /// One secondary solve of @p L for the primary border values @p border (L.borderDofs order)
    /// and, when @p loads is not null, its period-averaged loads on secondary dofs. Writes Gamma
    /// (L.gammaDofs order) to @p gammaOut and, when @p watchOut is not null, the watched nodes'
    /// values (3 per node). Direct quasi-static CHOLMOD layouts without loads take Gamma = R u_B
    /// (the field then goes stale, see refreshField()); the others solve the whole field.
    /// @return false (outputs undefined, state kept) when the solve failed or is not finite.
    bool solve(Layout& L, const double* border, const BorderPacket* loads, double* gammaOut,
               double* watchOut) noexcept;
    /// Solves the whole field of @p L for its last border when direct solves left it stale.
    void refreshField(Layout& L);
    /// Loads @p L's work state (x, v, a) from the coarse state.
    void warmStart(Layout& L) const noexcept;
    /// Contact change: the entry state of @p next (the nodes of its P and Gamma that were interior
    /// secondary nodes of @p from take @p from's latest solution) and its warm state; counts the
    /// preparation begun at @p begin.
    void prepareEntry(Layout& from, Layout& next, std::chrono::steady_clock::time_point begin);
    /// Adaptive switch (synchronous): coarse unknowns of @p to that were primary in @p from take
    /// the primary's displacement @p u and velocity ((u - uPrev) / dtSub); then warmStart(to).
    void takeFromPrimary(const Layout& from, Layout& to, const Eigen::VectorXd& u,
                         const Eigen::VectorXd& uPrev, double dtSub) noexcept;
    /// The counters, with @p used solutions taken up by the primary.
    AsyncSecondaryStats stats(std::uint64_t used) const noexcept;

  private:
    bool solveDirect(Layout& L, const double* border, double* gammaOut, double* watchOut) noexcept;
    bool solveField(Layout& L, const double* border, const BorderPacket* loads,
                    int& iterations) noexcept;
    void advanceScheme(Layout& L) noexcept;

    const AsyncSetup& mSetup;
    Eigen::VectorXd mUC, mVC, mAC;  // full coarse dof indexing
    std::atomic<std::uint64_t> mSolves{0};
    std::atomic<double> mLastSolve{0.0}, mMaxSolve{0.0}, mLastSolveCpu{0.0};
    std::atomic<int> mLastIterations{0};
    std::atomic<std::uint64_t> mPrepared{0};
    std::atomic<double> mLastPrepare{0.0};
};

}  // namespace palp::fem
