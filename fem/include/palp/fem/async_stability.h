#pragma once
/// @file
/// Stability of the asynchronous regions' plain (staggered) coupling (docs/algorithms.md section
/// 6, "Stability of the staggered coupling"). With the contact held, the synchronous scheme is a
/// linear map of its state over one secondary period: the primary's displacement at the last two
/// substeps on its free dofs, the two Gamma values the primary interpolates between and, for a
/// dynamic secondary, the secondary's displacement, velocity and acceleration. Its spectral
/// radius decides whether a run stays bounded (< 1) or grows without bound (> 1), whatever the
/// input.
///
/// The map is formed from the same regions and matrices AsyncRegions builds (LayoutBuilder), the
/// primary's central difference with its substep and mass damping, Gamma's linear interpolation
/// over the period, and the secondary's solve (quasi-static or Newmark / backward Euler) of the
/// border read at the period's end. It is the analysis of the scheme, not a run of it: the tests
/// compare its prediction with runs of AsyncRegions.

#include <complex>
#include <vector>

#include "palp/fem/async_regions.h"

namespace palp::fem {

/// Spectral radius of the staggered period map.
struct StaggeredStability {
    double spectralRadius = 0.0;      ///< largest |eigenvalue| of the period map
    std::complex<double> dominant{};  ///< that eigenvalue
    double growthPerPeriod = 0.0;     ///< power iteration: mean ||z_k+1|| / ||z_k|| at its end
    bool dense = false;               ///< eigenvalues of the formed matrix (else Arnoldi's)
    int stateSize = 0;                ///< dimension of the period map
    int periodTicks = 0;              ///< ticks per secondary period
    int substeps = 0;                 ///< primary substeps per tick
    int freeDofs = 0, gammaDofs = 0;  ///< free primary dofs, Gamma dofs
    int borderDofs = 0;               ///< primary border dofs
};

/// The period map of the plain coupling in synchronous mode for a displacement-driven contact
/// at @p contactNodes, on the layout of options.primaryNodes seeds (options.condensed, drive,
/// threads, adaptivity and watched nodes are ignored; plainLead and interpolate shape Gamma).
/// Quasi-static secondaries are formed densely (state 2 |free P| + 2 |Gamma|) and their
/// eigenvalues taken exactly when the state has at most @p denseLimit entries; dynamic
/// secondaries (and larger states) take the largest Ritz value of @p arnoldiSteps Arnoldi steps
/// on the matrix-free map (within a few % of rho(Phi) near 1, where a Ritz value of the
/// non-normal map can exceed it: compare growthPerPeriod). growthPerPeriod is the geometric mean
/// growth over the last quarter of @p powerPeriods periods of power iteration. Assembles and
/// factorises the secondary system once: about a second on a 13^3 cube, plus the eigenvalues.
/// @throw palp::ValueError as AsyncRegions's constructor for bad options or contact nodes, or
/// for a singular secondary system.
StaggeredStability staggeredStability(const FemModel& model, const Constraints& constraints,
                                      const std::vector<int>& contactNodes,
                                      const AsyncRegionsOptions& options, int denseLimit = 2500,
                                      int arnoldiSteps = 120, int powerPeriods = 400);

}  // namespace palp::fem
