#pragma once
/// @file
/// A watchdog around any Device: a device that stops delivering fresh samples, or delivers
/// samples no hand makes (non-finite, out of its workspace, too fast), gets zero force within a
/// set time, and force returns without a jump when good samples resume.

#include <Eigen/Core>
#include <cstdint>

#include "palp/haptics/devices/device.h"
#include "palp/haptics/devices/fault_ramp.h"

namespace palp::haptics {

/// When a device without fresh, good samples loses its force (times in s, counted in reads of
/// one servo period each, so offline steps and real-time ticks behave alike), and which samples
/// are bad.
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
    /// A position outside the device's workspace (DeviceSpec::workspace) grown by this on every
    /// side is out of range, m (0..10). A spec whose workspace box has no volume (not given)
    /// is checked against palp's world bound instead (|x|, |y|, |z| <= 10 m, bounds::kPosition).
    double workspaceMarginMeters = 0.1;
    /// A sample is too fast when its velocity's norm is above this, or when its position lies
    /// farther from the last good sample's than this speed covers in the reads since then plus
    /// one (a period of slack for a sample that arrived late), m/s (> 0 .. 1000). No hand moves
    /// 10 m/s (a quick human reach peaks near 2 m/s; desktop devices track less).
    double maxSpeedMps = 10.0;
};

/// @throw palp::ValueError naming the field (`watchdog timeoutSeconds: expected ...`) when a
/// time is not finite or out of range, or graceSeconds >= timeoutSeconds.
void validateWatchdogParams(const WatchdogParams& params);

/// Wraps a Device (a host's, a network's) and watches its samples.
///
/// Each read() reads the inner device and judges the sample (DeviceHealth::faults):
/// kFaultNonFinite (a NaN or infinite position, velocity or time), kFaultOutOfRange (outside
/// the workspace grown by workspaceMarginMeters), kFaultTooFast (maxSpeedMps), else
/// kFaultStale when its sequence and timestamp equal the last good sample's, else it is fresh.
/// A bad or stale read counts as missing: after s seconds of them (s = missing reads x period)
/// the force scale is 1 up to graceSeconds, then falls linearly to 0 at timeoutSeconds (a trip,
/// counted once per outage); a fresh sample lets it climb back at 1 / resumeSeconds per second
/// (never faster than it fell) (FaultRamp). health() reports it, and Session scales its force by
/// it (the snapshot's force and the passivity observer see the scaled force); write() also
/// limits the force's norm to forceScale x maxForceN, a last line for loops that ignore
/// health().
///
/// What read() returns: a fresh sample as is; a stale one as the last fresh sample with zero
/// velocity (the probe holds still, so no damping acts on a stale velocity); a bad one as it
/// came, so that its faults bits tell the caller to refuse it (Session holds the last good
/// force, Snapshot::faulted, exactly as for a NaN) while the watchdog counts it as missing.
/// The too-fast test measures from the last good sample, so one wild sample does not make the
/// good ones after it look like jumps.
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
    /// Passed on to the inner device.
    void reportFaults(std::uint32_t faults, double forceScale) noexcept override {
        mInner.reportFaults(faults, forceScale);
    }

    const WatchdogParams& params() const noexcept { return mParams; }

  private:
    /// kBadSampleFaults bits of @p s.
    std::uint32_t judge(const DeviceState& s) const noexcept;

    Device& mInner;
    WatchdogParams mParams;
    double mPeriod;
    FaultRamp mRamp;
    WorkspaceBox mRange;  // the workspace grown by the margin (or palp's world bound)
    bool mHaveSample = false;
    DeviceState mLast;  // the last fresh, good sample
    std::uint64_t mReadsSinceGood = 0;
    DeviceHealth mHealth;
};

}  // namespace palp::haptics
