#pragma once
/// @file
/// A watchdog around any Device: a device that stops delivering fresh samples gets zero force
/// within a set time, and force returns without a jump when samples resume.

#include <Eigen/Core>
#include <cstdint>

#include "palp/haptics/devices/device.h"

namespace palp::haptics {

/// When a device without fresh samples loses its force (times in s, counted in reads of one
/// servo period each, so offline steps and real-time ticks behave alike).
struct WatchdogParams {
    /// No fresh sample for this long: the force is zero (0 < graceSeconds < timeoutSeconds
    /// <= 10 s).
    double timeoutSeconds = 10e-3;
    /// No fresh sample for up to this long: the force is kept whole (a late sample or two of a
    /// jittery link is not felt); between grace and timeout it ramps linearly to zero (>= 0).
    double graceSeconds = 2e-3;
    /// Once samples are fresh again the force scale climbs back to 1 at 1 / resumeSeconds per
    /// second (0 .. 10 s; 0: at once), so a hand that moved while the samples were missing is
    /// not kicked by the stored coupling force.
    double resumeSeconds = 50e-3;
};

/// @throw palp::ValueError naming the field (`watchdog timeoutSeconds: expected ...`) when a
/// time is not finite or out of range, or graceSeconds >= timeoutSeconds.
void validateWatchdogParams(const WatchdogParams& params);

/// Wraps a Device (a host's, a network's) and watches its samples.
///
/// Each read() reads the inner device. A sample is fresh when its position and velocity are
/// finite and its sequence or timestamp differs from the last fresh sample's. After s seconds
/// without a fresh sample (s = stale reads x period) the force scale is 1 up to graceSeconds,
/// then falls linearly to 0 at timeoutSeconds (a trip, counted once per outage); a fresh sample
/// lets it climb back at 1 / resumeSeconds per second (never faster than it fell). health()
/// reports it, and Session scales its force by it (the snapshot's force and the passivity
/// observer see the scaled force); write() also limits the force's norm to forceScale x
/// maxForceN, a last line for loops that ignore health().
///
/// What read() returns: a fresh sample as is; a repeated finite one as the last fresh sample
/// with zero velocity (the probe holds still, so no damping acts on a stale velocity); a
/// non-finite one as is, so that Session's guard flags it (Snapshot::faulted) while the
/// watchdog counts it as missing.
///
/// @par Threading  Like any Device: read(), write() and health() from the servo thread only.
/// @par Real-time  noexcept, allocation-free, O(1) (plus the inner device's calls).
class WatchdogDevice final : public Device {
  public:
    /// @param inner the watched device (must outlive this one)
    /// @param periodSeconds servo period, s (one read per period)
    /// @throw palp::ValueError from validateWatchdogParams() or a period outside bounds::kPeriod.
    WatchdogDevice(Device& inner, const WatchdogParams& params, double periodSeconds);

    DeviceState read() noexcept override;
    void write(const Eigen::Vector3d& forceN) noexcept override;
    const DeviceSpec& spec() const noexcept override { return mInner.spec(); }
    DeviceHealth health() const noexcept override { return mHealth; }

    const WatchdogParams& params() const noexcept { return mParams; }

  private:
    Device& mInner;
    WatchdogParams mParams;
    double mPeriod;
    double mResumeStep;  // scale gained per fresh read
    bool mHaveSample = false;
    DeviceState mLast;  // the last fresh sample
    DeviceHealth mHealth;
};

}  // namespace palp::haptics
