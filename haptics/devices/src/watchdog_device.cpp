#include "palp/haptics/devices/watchdog_device.h"

#include <algorithm>
#include <cmath>
#include <string>

#include "palp/base/bounds.h"
#include "palp/base/error.h"
#include "palp/base/validate.h"
#include "palp/haptics/devices/fault_ramp.h"
#include "palp/haptics/rendering/safety.h"

namespace palp::haptics {

namespace {
constexpr double kMaxMarginMeters = 10.0;
constexpr double kMaxSpeedLimit = 1000.0;  // m/s
}  // namespace

void validateFaultRampTimes(std::string_view prefix, double graceSeconds, double timeoutSeconds,
                            double resumeSeconds) {
    const std::string p(prefix);
    requireInRange(p + "timeoutSeconds", timeoutSeconds, 0.0, kMaxFaultRampSeconds, "s");
    if (!(timeoutSeconds > 0))
        throwExpected(p + "timeoutSeconds", "a time > 0 s", formatValue(timeoutSeconds));
    requireInRange(p + "graceSeconds", graceSeconds, 0.0, kMaxFaultRampSeconds, "s");
    if (!(graceSeconds < timeoutSeconds)) {
        throwExpected(p + "graceSeconds",
                      "less than " + p + "timeoutSeconds (" + formatValue(timeoutSeconds) + " s)",
                      formatValue(graceSeconds));
    }
    requireInRange(p + "resumeSeconds", resumeSeconds, 0.0, kMaxFaultRampSeconds, "s");
}

void validateWatchdogParams(const WatchdogParams& params) {
    validateFaultRampTimes("watchdog ", params.graceSeconds, params.timeoutSeconds,
                           params.resumeSeconds);
    requireInRange("watchdog workspaceMarginMeters", params.workspaceMarginMeters, 0.0,
                   kMaxMarginMeters, "m");
    requireInRange("watchdog maxSpeedMps", params.maxSpeedMps, 0.0, kMaxSpeedLimit, "m/s");
    if (!(params.maxSpeedMps > 0)) {
        throwExpected("watchdog maxSpeedMps", "a speed > 0 m/s", formatValue(params.maxSpeedMps));
    }
}

WatchdogDevice::WatchdogDevice(Device& inner, const WatchdogParams& params, double periodSeconds)
    : mInner(inner), mParams(params), mPeriod(periodSeconds) {
    validateWatchdogParams(params);
    requireWithin("watchdog period", periodSeconds, bounds::kPeriod);
    mRamp =
        FaultRamp(params.graceSeconds, params.timeoutSeconds, params.resumeSeconds, periodSeconds);
    const WorkspaceBox& box = inner.spec().workspace;
    if ((box.size().array() > 0).all() && box.min.allFinite() && box.max.allFinite()) {
        const Eigen::Vector3d margin = Eigen::Vector3d::Constant(params.workspaceMarginMeters);
        mRange = WorkspaceBox{box.min - margin, box.max + margin};
    } else {
        mRange = WorkspaceBox{Eigen::Vector3d::Constant(bounds::kPosition.min),
                              Eigen::Vector3d::Constant(bounds::kPosition.max)};
    }
}

std::uint32_t WatchdogDevice::judge(const DeviceState& s) const noexcept {
    if (!(s.position.allFinite() && s.velocity.allFinite() && std::isfinite(s.timestampSeconds)))
        return kFaultNonFinite;
    std::uint32_t bad = 0;
    if (!mRange.contains(s.position)) bad |= kFaultOutOfRange;
    // Reads since the last good sample, this one included, plus one of slack.
    const double reach = mParams.maxSpeedMps * mPeriod * static_cast<double>(mReadsSinceGood + 1);
    if (s.velocity.norm() > mParams.maxSpeedMps ||
        (mHaveSample && (s.position - mLast.position).norm() > reach))
        bad |= kFaultTooFast;
    return bad;
}

DeviceState WatchdogDevice::read() noexcept {
    const DeviceState s = mInner.read();
    ++mReadsSinceGood;
    const std::uint32_t bad = judge(s);
    const bool fresh = bad == 0 && (!mHaveSample || s.sequence != mLast.sequence ||
                                    s.timestampSeconds != mLast.timestampSeconds);
    DeviceHealth& h = mHealth;
    if (fresh) {
        mLast = s;
        mHaveSample = true;
        mReadsSinceGood = 0;
        h.stale = false;
        h.staleTicks = 0;
        h.faults = 0;
        h.forceScale = mRamp.good();
        return s;
    }
    h.faults = bad != 0 ? bad : static_cast<std::uint32_t>(kFaultStale);
    h.stale = true;
    h.forceScale = mRamp.bad();
    h.staleTicks = mRamp.badTicks();
    h.trips = mRamp.trips();
    if (bad != 0 || !mHaveSample) return s;  // the caller refuses a bad sample (Session)
    DeviceState held = mLast;
    held.velocity.setZero();
    return held;
}

void WatchdogDevice::write(const Eigen::Vector3d& forceN) noexcept {
    mInner.write(clampForce(forceN, mHealth.forceScale * mInner.spec().maxForceN));
}

}  // namespace palp::haptics
