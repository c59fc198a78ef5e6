#pragma once
/// @file
/// Last-line force safety for the servo loop: clamp to the device maximum, a guard against
/// non-finite forces, a start-up gate, and cross-faded parameter changes.
///
/// @par Threading
/// Each object belongs to one servo loop; all calls from the servo thread.
/// @par Real-time
/// Everything here is noexcept, allocation-free and O(1).

#include <Eigen/Core>
#include <cmath>
#include <cstdint>

namespace palp::haptics {

/// @p forceN (N) scaled down, direction preserved, so that its norm is at most @p maxForceN
/// (N, >= 0). A non-finite input gives zero (use ForceGuard to hold the last good force instead).
/// @par Real-time
inline Eigen::Vector3d clampForce(const Eigen::Vector3d& forceN, double maxForceN) noexcept {
    const double n = forceN.norm();
    if (!std::isfinite(n)) return Eigen::Vector3d::Zero();
    if (!(maxForceN > 0.0)) return Eigen::Vector3d::Zero();
    if (n <= maxForceN) return forceN;
    return forceN * (maxForceN / n);
}

/// Replaces a force with a NaN or Inf component by the last finite one and raises a flag.
class ForceGuard {
  public:
    /// Returns @p forceN when all components are finite (and remembers it), otherwise the last
    /// finite force (zero before any) and sets faulted().
    /// @par Real-time
    Eigen::Vector3d filter(const Eigen::Vector3d& forceN) noexcept {
        if (forceN.allFinite()) {
            mLastGood = forceN;
            return forceN;
        }
        mFaulted = true;
        ++mFaultCount;
        return mLastGood;
    }
    /// True once a non-finite force has been seen, until clearFault().
    bool faulted() const noexcept { return mFaulted; }
    /// Number of ticks with a non-finite force since construction.
    std::uint64_t faultCount() const noexcept { return mFaultCount; }
    /// Lowers the flag (the count stays).
    void clearFault() noexcept { mFaulted = false; }
    /// The force returned for a non-finite input, N.
    const Eigen::Vector3d& lastGood() const noexcept { return mLastGood; }

  private:
    Eigen::Vector3d mLastGood{Eigen::Vector3d::Zero()};
    bool mFaulted = false;
    std::uint64_t mFaultCount = 0;
};

/// Sends no force until the computed force has stayed below a threshold for a number of
/// consecutive ticks (so a loop started with the probe inside an object does not kick the
/// user). Once open, it stays open until reset().
class StartupGate {
  public:
    /// @param thresholdN force norm, N, below which a tick counts as quiet
    /// @param quietTicks consecutive quiet ticks needed to open (0 opens at once)
    StartupGate(double thresholdN, std::uint32_t quietTicks) noexcept
        : mThreshold(thresholdN), mQuietTicksNeeded(quietTicks), mOpen(quietTicks == 0) {}

    /// @p forceN once the gate is open, zero before. The tick that completes the quiet run
    /// opens the gate and already passes its (small) force through.
    /// @par Real-time
    Eigen::Vector3d filter(const Eigen::Vector3d& forceN) noexcept {
        if (!mOpen) {
            const double n = forceN.norm();
            mQuiet = (n < mThreshold) ? mQuiet + 1 : 0;  // NaN counts as loud
            if (mQuiet >= mQuietTicksNeeded) mOpen = true;
        }
        return mOpen ? forceN : Eigen::Vector3d::Zero();
    }
    /// Whether force passes.
    bool open() const noexcept { return mOpen; }
    /// Closes the gate again (e.g. after a mode change that may jump the force).
    void reset() noexcept {
        mQuiet = 0;
        mOpen = mQuietTicksNeeded == 0;
    }

  private:
    double mThreshold;
    std::uint32_t mQuietTicksNeeded;
    std::uint32_t mQuiet = 0;
    bool mOpen;
};

/// A parameter (stiffness, damping, a mode blend weight) that moves linearly to a new target
/// over a given number of ticks instead of jumping.
class CrossFade {
  public:
    /// Starts settled at @p value.
    explicit CrossFade(double value = 0.0) noexcept : mFrom(value), mTo(value) {}

    /// Fades from the current value to @p target over @p ticks calls of step() (0: at once).
    void setTarget(double target, std::uint32_t ticks) noexcept {
        mFrom = value();
        mTo = target;
        mTicks = ticks;
        mDone = 0;
    }
    /// Advances one tick and returns the new value; after `ticks` steps it equals the target
    /// exactly.
    /// @par Real-time
    double step() noexcept {
        if (mDone < mTicks) ++mDone;
        return value();
    }
    /// Current value.
    double value() const noexcept {
        if (mDone >= mTicks) return mTo;
        const double s = static_cast<double>(mDone) / static_cast<double>(mTicks);
        return mFrom + s * (mTo - mFrom);
    }
    /// Value the fade ends at.
    double target() const noexcept { return mTo; }
    /// True while a fade is in progress.
    bool fading() const noexcept { return mDone < mTicks; }

  private:
    double mFrom;
    double mTo;
    std::uint32_t mTicks = 0;
    std::uint32_t mDone = 0;
};

}  // namespace palp::haptics
