#pragma once
/// @file
/// Offline runs of a session over a scripted trajectory: stepping it on the calling thread and
/// keeping its snapshots, the duration a trajectory needs, and the figures of a run.

#include <cstdint>
#include <span>
#include <vector>

#include "palp/haptics/devices/trajectory.h"
#include "palp/haptics/session.h"

namespace palp::haptics {

/// Steps @p session (not running) @p ticks times with Session::step() on the calling thread
/// and returns every @p every-th snapshot (the last tick's always included).
/// @throw palp::ValueError for every == 0.
std::vector<Snapshot> runOffline(Session& session, std::uint64_t ticks, std::uint64_t every = 1);

/// Duration (s) after which @p trajectory has done what it scripts: the approach plus
/// @p passes passes for a sweep (length / speed + turn per pass), durationSeconds() for a
/// raster, the approach plus @p passes revolutions for a circle, 2 press + hold for a press,
/// @p passes periods (plus growSeconds) for a sinusoid.
double trajectoryDuration(const Trajectory& trajectory, int passes = 1) noexcept;

/// Figures of one run.
struct RunSummary {
    std::uint64_t ticks = 0;
    double seconds = 0;              ///< simulated (snapshot) time covered, s
    double maxForceN = 0;            ///< largest |force| sent, N
    double finalObserverEnergy = 0;  ///< passivity W at the end, J
    double minObserverEnergy = 0;    ///< smallest W seen, J (negative: the observer saw energy
                                     ///< generated)
    double meanRays = 0;             ///< rays per tick, mean over ticks with a ray bundle
    int maxRays = 0;
    double contactFraction = 0;                 ///< share of ticks with the proxy on a surface
    double minStiffness = 0, maxStiffness = 0;  ///< over contact ticks, N/m
    std::uint64_t faultedTicks = 0, clampedTicks = 0;
};
RunSummary summarize(std::span<const Snapshot> snapshots) noexcept;

}  // namespace palp::haptics
