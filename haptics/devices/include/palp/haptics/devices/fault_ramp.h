#pragma once
/// @file
/// The force scale of a fault that lasts: kept whole through a grace time, then ramped linearly
/// to zero at a timeout, and climbed back at a set rate once the fault clears. WatchdogDevice
/// (missing or bad samples) and Session (bad samples and forces of any device) share it, so
/// every fault ends in the same ramp.

#include <algorithm>
#include <cstdint>
#include <string_view>

namespace palp::haptics {

/// Longest grace, timeout or resume time a FaultRamp's owner accepts, s.
inline constexpr double kMaxFaultRampSeconds = 10.0;

/// The set-up check of a FaultRamp's times, shared by its owners (WatchdogParams, the session's
/// FaultParams): 0 < timeout, 0 <= grace < timeout, 0 <= resume, each at most
/// kMaxFaultRampSeconds. @p prefix names the owner's fields, e.g. "watchdog " or "session
/// faults.". @throw palp::ValueError naming the field, e.g. `watchdog graceSeconds`.
void validateFaultRampTimes(std::string_view prefix, double graceSeconds, double timeoutSeconds,
                            double resumeSeconds);

/// Times are counted in ticks of one period, so offline steps and real-time ticks behave alike.
///
/// After n consecutive bad() ticks (s = n x period) the scale allowed is 1 up to graceSeconds,
/// (timeout - s) / (timeout - grace) between grace and timeout, 0 from the timeout on (a trip,
/// counted once per outage); the scale never rises during an outage. Each good() tick ends the
/// outage and raises the scale by period / resumeSeconds (at once to 1 when resumeSeconds is 0).
///
/// @par Threading  One owner thread (the servo thread).
/// @par Real-time  noexcept, allocation-free, O(1).
class FaultRamp {
  public:
    FaultRamp() = default;
    /// @param graceSeconds, timeoutSeconds, resumeSeconds  checked by the owner
    ///        (validateFaultRampTimes)
    /// @param periodSeconds  one tick, s (> 0)
    FaultRamp(double graceSeconds, double timeoutSeconds, double resumeSeconds,
              double periodSeconds) noexcept
        : mGrace(graceSeconds),
          mTimeout(timeoutSeconds),
          mPeriod(periodSeconds),
          mResumeStep(resumeSeconds > 0 ? periodSeconds / resumeSeconds : 1.0) {}

    /// One tick with the fault; returns the new scale.
    double bad() noexcept {
        ++mBadTicks;
        const double s = static_cast<double>(mBadTicks) * mPeriod;
        double allowed = 1.0;
        if (s >= mTimeout) {
            allowed = 0.0;
        } else if (s > mGrace) {
            allowed = (mTimeout - s) / (mTimeout - mGrace);
        }
        if (mScale > 0 && allowed <= 0) ++mTrips;
        mScale = std::min(mScale, allowed);
        return mScale;
    }
    /// One tick without it; returns the new scale.
    double good() noexcept {
        mBadTicks = 0;
        mScale = std::min(1.0, mScale + mResumeStep);
        return mScale;
    }

    double scale() const noexcept { return mScale; }               ///< 0..1
    std::uint64_t badTicks() const noexcept { return mBadTicks; }  ///< consecutive
    std::uint64_t trips() const noexcept { return mTrips; }        ///< outages that hit 0
    double graceSeconds() const noexcept { return mGrace; }        ///< s
    double timeoutSeconds() const noexcept { return mTimeout; }    ///< s

  private:
    double mGrace = 2e-3;
    double mTimeout = 10e-3;
    double mPeriod = 1e-3;
    double mResumeStep = 1e-3 / 50e-3;
    double mScale = 1.0;
    std::uint64_t mBadTicks = 0;
    std::uint64_t mTrips = 0;
};

}  // namespace palp::haptics
