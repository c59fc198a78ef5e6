#pragma once
/// @file
/// CouplingSpring: the virtual-coupling spring between a haptic probe and deformable tissue,
/// solved inside the explicit substeps of a tick (docs/algorithms.md section 10) so that the
/// coupling and the tissue are integrated together: any coupling stiffness is stable once the
/// substep accounts for it (springFrequencySquared), where a force applied one tick late rings
/// as soon as k exceeds the tissue's local stiffness.
///
/// The spring pulls the weighted displacement of a set of free nodes, `a(u) = sum_i w_i u_i`
/// (weights >= 0 summing to 1: the contact filter), towards a target `c` (metres, displacement
/// space: where the contact point would have to move for the spring to relax). The total force
/// on the tissue is `F = clamp(k (c - a(u)), maxForce)` (clamped in magnitude), and node i carries
/// `w_i F`. It is the gradient of the potential `U = H(|c - a|)` (quadratic, then linear beyond
/// the clamp), so it is conservative: the spring adds no energy to the tissue.
///
/// An optional damper of @c damping (N s/m) acts on the velocity of a(u), to ground, along
/// with the spring: the spring alone, on the light surface under a stiff coupling, is a fast
/// undamped mode that makes the surface overshoot the probe. It is the tissue's own viscosity at
/// the contact (like its mass-proportional damping), not part of the contact force the step
/// reports: the hand feels it through the spring, as the surface it brakes lags the probe. It
/// enters the central-difference update implicitly, like mass-proportional damping (the rank-one
/// term `b w w^T` of the damping matrix is solved exactly by Sherman-Morrison, per direction,
/// over the spring's nodes), so it never limits the step. criticalDamping() gives
/// `2 sqrt(k m_eff)`, `m_eff = 1 / sum w_i^2 / m_i`.
///
/// Each solver evaluates F at every substep from the current displacement, adds `w_i F` to the
/// nodal loads of that substep, and reports the mean force over the step (the impulse divided
/// by the time) and the final one.

#include <Eigen/Core>
#include <limits>
#include <span>

#include "palp/fem/fem_model.h"

namespace palp::fem {

/// A coupling spring for one step (see the file comment). The spans must stay valid for the
/// step; they are only read.
struct CouplingSpring {
    std::span<const int> nodes;       ///< free nodes carrying the spring (fine node indices)
    std::span<const double> weights;  ///< one per node, >= 0, summing to 1
    Eigen::Vector3d target = Eigen::Vector3d::Zero();           ///< c, metres (displacement space)
    double stiffness = 0.0;                                     ///< k, N/m; 0: no spring
    double maxForce = std::numeric_limits<double>::infinity();  ///< |F| clamp, N (> 0)
    double damping = 0.0;  ///< b, N s/m, on the velocity of a(u), to ground (>= 0), implicit
    /// The target's velocity v (m/s; the probe's): within a step the target moves as
    /// `c + v t` (t from the step's start), as the probe does.
    Eigen::Vector3d targetVelocity = Eigen::Vector3d::Zero();

    /// True when the spring acts: k > 0, finite, and at least one node.
    bool active() const noexcept;
};

/// What a spring did over one step.
struct SpringResult {
    Eigen::Vector3d meanForce = Eigen::Vector3d::Zero();  ///< impulse / time, N, on the tissue
    Eigen::Vector3d endForce = Eigen::Vector3d::Zero();   ///< force of the last substep, N
    Eigen::Vector3d endPoint = Eigen::Vector3d::Zero();   ///< a(u) at the end of the step, m
    bool clamped = false;  ///< some substep's force was clamped to maxForce
};

/// F = k (c - a) clamped to |F| <= maxForce (zero for a non-finite result). @par Real-time
Eigen::Vector3d springForce(const CouplingSpring& spring, const Eigen::Vector3d& a) noexcept;

/// The most the spring raises the squared highest angular frequency of the lumped-mass system:
/// `k sum_i w_i^2 / m_i`, m_i the node's lumped mass (rad^2/s^2; the spring's stiffness matrix
/// is `k w w^T` per direction, whose largest eigenvalue under M is this sum). Nodes without
/// mass count as infinite frequency. @par Real-time  O(#nodes).
double springFrequencySquared(const FemModel& model, const CouplingSpring& spring) noexcept;

/// `ratio * 2 sqrt(k m_eff)` with `m_eff = 1 / sum_i w_i^2 / m_i`: the damping (N s/m) that
/// damps the spring on the contact's effective mass at @p ratio of critical. @par Real-time
double criticalDamping(const FemModel& model, const CouplingSpring& spring, double ratio) noexcept;

/// The critical central-difference step of @p model (FemModel::criticalTimeStep()'s formula,
/// Rayleigh damping included) with the highest angular frequency raised to
/// `sqrt(w_max^2 + extraOmega2)`, seconds. @par Real-time
double criticalTimeStepWith(const FemModel& model, double extraOmega2) noexcept;

}  // namespace palp::fem
