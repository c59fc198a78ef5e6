#include "palp/studies/offline_run.h"

#include <algorithm>
#include <limits>
#include <type_traits>
#include <variant>

#include "in_contact.h"
#include "palp/base/error.h"

namespace palp::haptics {

std::vector<Snapshot> runOffline(Session& session, std::uint64_t ticks, std::uint64_t every) {
    if (every == 0) {
        throw ValueError("runOffline: expected a snapshot interval 'every' >= 1, found 0");
    }
    std::vector<Snapshot> out;
    out.reserve(static_cast<std::size_t>(ticks / every + 1));
    for (std::uint64_t i = 0; i < ticks; ++i) {
        const Snapshot& s = session.step();
        if (i % every == 0 || i + 1 == ticks) out.push_back(s);
    }
    return out;
}

double trajectoryDuration(const Trajectory& trajectory, int passes) noexcept {
    const double n = std::max(passes, 1);
    return std::visit(
        [n](const auto& t) -> double {
            using T = std::decay_t<decltype(t)>;
            if constexpr (std::is_same_v<T, PressTrajectory>) {
                return 2 * t.pressSeconds + t.holdSeconds;
            } else if constexpr (std::is_same_v<T, SweepTrajectory>) {
                return t.approachSeconds + n * (t.lengthM / t.speedMps + t.turnSeconds);
            } else if constexpr (std::is_same_v<T, RasterTrajectory>) {
                return t.durationSeconds();
            } else if constexpr (std::is_same_v<T, CircleTrajectory>) {
                return t.approachSeconds + n / t.frequencyHz;
            } else {
                return t.growSeconds + n / t.frequencyHz;
            }
        },
        trajectory);
}

RunSummary summarize(std::span<const Snapshot> snapshots) noexcept {
    RunSummary r;
    if (snapshots.empty()) return r;
    r.ticks = snapshots.size();
    r.seconds = snapshots.back().timeSeconds - snapshots.front().timeSeconds;
    r.minObserverEnergy = std::numeric_limits<double>::infinity();
    r.minStiffness = std::numeric_limits<double>::infinity();
    r.maxStiffness = 0;
    double raySum = 0;
    std::uint64_t rayTicks = 0, contacts = 0;
    for (const Snapshot& s : snapshots) {
        r.maxForceN = std::max(r.maxForceN, s.force.norm());
        r.minObserverEnergy = std::min(r.minObserverEnergy, s.observerEnergy);
        if (s.rays > 0) {
            raySum += s.rays;
            ++rayTicks;
        }
        r.maxRays = std::max(r.maxRays, s.rays);
        if (detail::inContact(s)) {
            ++contacts;
            r.minStiffness = std::min(r.minStiffness, s.stiffness);
            r.maxStiffness = std::max(r.maxStiffness, s.stiffness);
        }
        if (s.faulted) ++r.faultedTicks;
        if (s.clamped) ++r.clampedTicks;
    }
    r.finalObserverEnergy = snapshots.back().observerEnergy;
    r.meanRays = rayTicks ? raySum / static_cast<double>(rayTicks) : 0.0;
    r.contactFraction = static_cast<double>(contacts) / static_cast<double>(snapshots.size());
    if (contacts == 0) r.minStiffness = 0;
    return r;
}

}  // namespace palp::haptics
