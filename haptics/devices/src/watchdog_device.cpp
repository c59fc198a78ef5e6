#include "palp/haptics/devices/watchdog_device.h"

#include <algorithm>
#include <cmath>

#include "palp/base/bounds.h"
#include "palp/base/error.h"
#include "palp/base/validate.h"
#include "palp/haptics/rendering/safety.h"

namespace palp::haptics {

namespace {
constexpr double kMaxWatchdogSeconds = 10.0;
}  // namespace

void validateWatchdogParams(const WatchdogParams& params) {
    requireInRange("watchdog timeoutSeconds", params.timeoutSeconds, 0.0, kMaxWatchdogSeconds, "s");
    if (!(params.timeoutSeconds > 0)) {
        throwExpected("watchdog timeoutSeconds", "a time > 0 s",
                      formatValue(params.timeoutSeconds));
    }
    requireInRange("watchdog graceSeconds", params.graceSeconds, 0.0, kMaxWatchdogSeconds, "s");
    if (!(params.graceSeconds < params.timeoutSeconds)) {
        throwExpected("watchdog graceSeconds",
                      "less than timeoutSeconds (" + formatValue(params.timeoutSeconds) + " s)",
                      formatValue(params.graceSeconds));
    }
    requireInRange("watchdog resumeSeconds", params.resumeSeconds, 0.0, kMaxWatchdogSeconds, "s");
}

WatchdogDevice::WatchdogDevice(Device& inner, const WatchdogParams& params, double periodSeconds)
    : mInner(inner), mParams(params), mPeriod(periodSeconds) {
    validateWatchdogParams(params);
    requireWithin("watchdog period", periodSeconds, bounds::kPeriod);
    mResumeStep = params.resumeSeconds > 0 ? periodSeconds / params.resumeSeconds : 1.0;
}

DeviceState WatchdogDevice::read() noexcept {
    const DeviceState s = mInner.read();
    const bool finite =
        s.position.allFinite() && s.velocity.allFinite() && std::isfinite(s.timestampSeconds);
    const bool fresh = finite && (!mHaveSample || s.sequence != mLast.sequence ||
                                  s.timestampSeconds != mLast.timestampSeconds);
    DeviceHealth& h = mHealth;
    if (fresh) {
        mLast = s;
        mHaveSample = true;
        h.stale = false;
        h.staleTicks = 0;
        h.forceScale = std::min(1.0, h.forceScale + mResumeStep);
        return s;
    }
    h.stale = true;
    ++h.staleTicks;
    const double staleSeconds = static_cast<double>(h.staleTicks) * mPeriod;
    double allowed = 1.0;
    if (staleSeconds >= mParams.timeoutSeconds) {
        allowed = 0.0;
    } else if (staleSeconds > mParams.graceSeconds) {
        allowed = (mParams.timeoutSeconds - staleSeconds) /
                  (mParams.timeoutSeconds - mParams.graceSeconds);
    }
    if (h.forceScale > 0 && allowed <= 0) ++h.trips;
    h.forceScale = std::min(h.forceScale, allowed);
    if (!finite || !mHaveSample) return s;  // Session's guard flags a bad sample
    DeviceState held = mLast;
    held.velocity.setZero();
    return held;
}

void WatchdogDevice::write(const Eigen::Vector3d& forceN) noexcept {
    mInner.write(clampForce(forceN, mHealth.forceScale * mInner.spec().maxForceN));
}

}  // namespace palp::haptics
