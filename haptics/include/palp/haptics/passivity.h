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

/// Accumulates W(n) and, when enabled, adds just enough damping to keep it non-negative.
///
/// @par Threading
/// One instance per servo loop; all calls from the servo thread.
/// @par Real-time
/// Every member is noexcept, allocation-free and O(1).
class PassivityController {
  public:
    /// @param periodSeconds sample period T, s (> 0)
    /// @param enabled when false only the observer runs and forces pass through unchanged
    /// @param maxDampingNspm cap on the added damping, N s/m (e.g. DeviceSpec::maxDampingNspm);
    ///        when it binds, W can stay negative and the caller sees it through energy()
    explicit PassivityController(
        double periodSeconds, bool enabled = true,
        double maxDampingNspm = std::numeric_limits<double>::infinity()) noexcept
        : mPeriod(periodSeconds), mEnabled(enabled), mMaxDamping(maxDampingNspm) {}

    /// One tick: books the environment's force @p forceN (N, on the user) against the
    /// velocity @p velocityMps (m/s) and returns the force to send. When the controller is
    /// enabled and W would go negative, the returned force is `F - alpha v` with
    /// `alpha = -W / (T |v|^2)` (capped at maxDampingNspm); the energy it dissipates,
    /// `T alpha |v|^2`, is booked back into W.
    /// @par Real-time
    Eigen::Vector3d update(const Eigen::Vector3d& forceN,
                           const Eigen::Vector3d& velocityMps) noexcept {
        mEnergy -= mPeriod * forceN.dot(velocityMps);
        mAlpha = 0.0;
        if (!mEnabled || !(mEnergy < 0.0)) return forceN;
        const double v2 = velocityMps.squaredNorm();
        // With v = 0 damping cannot dissipate anything this tick (and no energy flowed either).
        if (!(v2 > 0.0) || !(mPeriod > 0.0)) return forceN;
        double alpha = -mEnergy / (mPeriod * v2);
        if (alpha > mMaxDamping) alpha = mMaxDamping;
        mAlpha = alpha;
        mEnergy += mPeriod * alpha * v2;
        if (mEnergy < 0.0 && alpha < mMaxDamping) mEnergy = 0.0;  // rounding only
        mDissipated += mPeriod * alpha * v2;
        return forceN - alpha * velocityMps;
    }

    /// W(n): energy absorbed by the environment (including the controller's damping), J.
    double energy() const noexcept { return mEnergy; }
    /// Damping alpha added in the last tick, N s/m (0 when none).
    double addedDamping() const noexcept { return mAlpha; }
    /// Total energy dissipated by the controller since construction or reset(), J.
    double dissipatedEnergy() const noexcept { return mDissipated; }
    /// Whether the controller (not only the observer) is active.
    bool enabled() const noexcept { return mEnabled; }
    /// Turns the controller on or off; the observer always runs.
    void setEnabled(bool enabled) noexcept { mEnabled = enabled; }
    /// Sets W back to zero (e.g. at the start of a session).
    void reset() noexcept {
        mEnergy = 0.0;
        mAlpha = 0.0;
        mDissipated = 0.0;
    }

  private:
    double mPeriod;
    bool mEnabled;
    double mMaxDamping;
    double mEnergy = 0.0;
    double mAlpha = 0.0;
    double mDissipated = 0.0;
};

}  // namespace palp::haptics
