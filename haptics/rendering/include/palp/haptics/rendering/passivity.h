#pragma once
/// @file
/// Time-domain passivity observer and controller (Hannaford and Ryu; docs/algorithms.md section 4).
///
/// Sign convention: `F` is the force the device applies to the user's hand and `v` the hand's
/// (end-effector's) velocity, both in the same frame. `F . v` is then the power flowing from the
/// virtual environment into the user, so the energy the environment has absorbed from the user is
///
///     W(n) = -T sum_{k<=n} F(k) . v(k)      (J)
///
/// A passive environment never returns more energy than it received: W(n) >= 0 for all n. A
/// spring `F = -k x` gives W(n) >= k |x(n)|^2 / 2 >= 0 when `v` is the backward difference of
/// `x`; an active element (negative damping, `F = +c v`) drives W negative.

#include <Eigen/Core>
#include <limits>

namespace palp::haptics {

/// Accumulates W(n) and, when enabled, keeps it non-negative: first with damping along the
/// hand's velocity (up to what the device renders, maxDampingNspm), then, where that is not
/// enough, by cutting the force's component along the velocity (a time-domain passivity
/// controller with the observed energy as its reservoir).
///
/// @par Threading
/// One instance per servo loop; all calls from the servo thread.
/// @par Real-time
/// Every member is noexcept, allocation-free and O(1).
class PassivityController {
  public:
    /// @param periodSeconds sample period T, s (> 0)
    /// @param enabled when false only the observer runs and forces pass through (clamped)
    /// @param maxDampingNspm cap on the added damping, N s/m (e.g. DeviceSpec::maxDampingNspm)
    /// @param maxForceN the device's force limit, N: update() clamps its output here before
    ///        booking it (infinite: no clamp)
    explicit PassivityController(
        double periodSeconds, bool enabled = true,
        double maxDampingNspm = std::numeric_limits<double>::infinity(),
        double maxForceN = std::numeric_limits<double>::infinity()) noexcept
        : mPeriod(periodSeconds),
          mEnabled(enabled),
          mMaxDamping(maxDampingNspm),
          mMaxForce(maxForceN) {}

    /// One tick: returns the force to send for the environment's force @p forceN (N, on the
    /// user) and the hand's velocity @p velocityMps (m/s), and books it into W.
    ///
    /// Controller enabled and W(n-1) - T F.v < 0 (the environment would return more than it
    /// absorbed): damping alpha = (T F.v - W(n-1)) / (T |v|^2) along v, capped at
    /// maxDampingNspm; if the cap binds, the force's component along v is cut by what remains,
    /// so that the booked power is exactly W(n-1) / T. The result is clamped to maxForceN
    /// (which only lowers the power the force delivers) and booked: W(n) = W(n-1) - T F_out.v.
    /// So while enabled, W never goes below zero (up to rounding). With v = 0 no energy flows
    /// and the force passes unchanged. Disabled: the force is clamped and booked only.
    /// @par Real-time
    Eigen::Vector3d update(const Eigen::Vector3d& forceN,
                           const Eigen::Vector3d& velocityMps) noexcept {
        mAlpha = 0.0;
        mCut = 0.0;
        Eigen::Vector3d out = forceN;
        const double v2 = velocityMps.squaredNorm();
        const double budget = mEnergy > 0.0 ? mEnergy : 0.0;  // what may flow out this tick
        const double outflow = mPeriod * forceN.dot(velocityMps);
        if (mEnabled && outflow > budget && v2 > 0.0 && mPeriod > 0.0) {
            const double excess = outflow - budget;  // J to remove along v
            double alpha = excess / (mPeriod * v2);
            if (alpha > mMaxDamping) alpha = mMaxDamping;
            mAlpha = alpha;
            out -= alpha * velocityMps;
            const double left = excess - mPeriod * alpha * v2;
            if (left > 0.0) {
                // Damping alone cannot: cut the force along v by the rest.
                const double beta = left / (mPeriod * v2);
                out -= beta * velocityMps;
                mCut = beta * std::sqrt(v2);
            }
        }
        const double n = out.norm();
        if (n > mMaxForce) out *= mMaxForce / n;
        const double booked = mPeriod * out.dot(velocityMps);
        if (mEnabled)
            mDissipated += mPeriod * forceN.dot(velocityMps) - booked > 0.0
                               ? mPeriod * forceN.dot(velocityMps) - booked
                               : 0.0;
        mEnergy -= booked;
        if (mEnabled && mEnergy < 0.0 && mEnergy > -1e-15) mEnergy = 0.0;  // rounding only
        return out;
    }

    /// W(n): energy absorbed by the environment (including the controller's action), J.
    double energy() const noexcept { return mEnergy; }
    /// Damping alpha added in the last tick, N s/m (0 when none).
    double addedDamping() const noexcept { return mAlpha; }
    /// Force cut along the velocity in the last tick beyond the damping, N (0 when none).
    double forceCut() const noexcept { return mCut; }
    /// Energy the controller kept from the hand since construction or reset(), J.
    double dissipatedEnergy() const noexcept { return mDissipated; }
    /// Whether the controller (not only the observer) is active.
    bool enabled() const noexcept { return mEnabled; }
    /// Turns the controller on or off; the observer always runs.
    void setEnabled(bool enabled) noexcept { mEnabled = enabled; }
    /// Sets W back to zero (e.g. at the start of a session).
    void reset() noexcept {
        mEnergy = 0.0;
        mAlpha = 0.0;
        mCut = 0.0;
        mDissipated = 0.0;
    }

  private:
    double mPeriod;
    bool mEnabled;
    double mMaxDamping;
    double mMaxForce;
    double mEnergy = 0.0;
    double mAlpha = 0.0;
    double mCut = 0.0;
    double mDissipated = 0.0;
};

}  // namespace palp::haptics
