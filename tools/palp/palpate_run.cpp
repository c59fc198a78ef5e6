// palp palpate's run (palpate_run.h).

#include "palpate_run.h"

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <thread>

#include "progress.h"

namespace palp::tool {

using nlohmann::json;

RunResult runRealtime(haptics::Session& session, std::uint64_t ticks, double wallSeconds) {
    RunResult r;
    std::vector<haptics::Snapshot>& snaps = r.snaps;
    std::uint64_t& traceDropped = r.traceDropped;
    const auto t0 = std::chrono::steady_clock::now();
    snaps.reserve(static_cast<std::size_t>(ticks) + 16);
    session.start();
    // Drain the per-tick trace ring (one row per tick, in order) until the servo
    // has run the asked-for ticks, then once more after stop() for the last ones.
    haptics::Snapshot s;
    const auto drain = [&] {
        while (session.popTrace(s)) snaps.push_back(s);
    };
    const InterruptGuard guard;
    const palp::volume::ProgressFn progress = progressLine("palp palpate: real time");
    const auto started = std::chrono::steady_clock::now();
    const auto wall = [&] {
        return std::chrono::duration<double>(std::chrono::steady_clock::now() - started).count();
    };
    // Wall-clock seconds when asked for, else the path's ticks.
    const auto fraction = [&] {
        return wallSeconds > 0
                   ? wall() / wallSeconds
                   : static_cast<double>(session.latest().tick + 1) / static_cast<double>(ticks);
    };
    while (fraction() < 1.0 && !InterruptGuard::interrupted()) {
        drain();
        if (progress) progress(std::min(fraction(), 1.0));
        std::this_thread::sleep_for(std::chrono::milliseconds(1));
    }
    session.stop();
    endProgress();
    r.interrupted = InterruptGuard::signal();
    drain();
    traceDropped = session.traceDropped();
    if (traceDropped > 0)
        std::fprintf(stderr,
                     "palp: warning: the trace ring dropped %llu snapshots (the "
                     "reader fell behind); the trace, map and summary miss those "
                     "ticks\n",
                     static_cast<unsigned long long>(traceDropped));
    r.wallSeconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    const haptics::ServoStats st = session.stats();
    const haptics::RealtimeStatus& rs = session.realtime();
    char b[512];
    std::snprintf(b, sizeof b,
                  "servo: %llu ticks, %llu missed, %llu skipped; wake latency "
                  "p50 %.1f us p99 %.1f us max %.1f us; tick compute p50 %.1f us "
                  "p99 %.1f us max %.1f us\nreal-time: %s",
                  static_cast<unsigned long long>(st.ticks),
                  static_cast<unsigned long long>(st.misses),
                  static_cast<unsigned long long>(st.skipped), st.wakeLatency.p50 * 1e6,
                  st.wakeLatency.p99 * 1e6, st.wakeLatency.max * 1e6, st.compute.p50 * 1e6,
                  st.compute.p99 * 1e6, st.compute.max * 1e6, rs.message.c_str());
    r.loopText = b;
    r.loopJson = {{"ticks", st.ticks},
                  {"misses", st.misses},
                  {"skipped", st.skipped},
                  {"wake_latency_us",
                   {{"p50", st.wakeLatency.p50 * 1e6},
                    {"p99", st.wakeLatency.p99 * 1e6},
                    {"max", st.wakeLatency.max * 1e6}}},
                  {"compute_us",
                   {{"p50", st.compute.p50 * 1e6},
                    {"p99", st.compute.p99 * 1e6},
                    {"max", st.compute.max * 1e6}}},
                  {"overloaded", st.overloaded},
                  {"fifo_dropped", st.fifoDropped},
                  {"overloaded_at_s", st.overloadedAtSeconds},
                  {"overloaded_missed_fraction", st.missedFraction},
                  {"shedding", st.shedding},
                  {"sheds", st.sheds},
                  {"restores", st.restores},
                  {"shed_at_s", st.shedAtSeconds},
                  {"realtime", rs.message},
                  {"trace_dropped", traceDropped}};
    if (st.sheds > 0 && !st.overloaded) {
        std::fprintf(stderr,
                     "palp: warning: the servo loop fell behind and shed work %llu time(s) (the "
                     "last at %.2f s: VC in place of AVC/AVCEC, deformable tissue frozen)%s\n",
                     static_cast<unsigned long long>(st.sheds), st.shedAtSeconds,
                     st.shedding ? "; still shed at the end" : "; restored since");
    }
    if (st.overloaded) {
        std::fprintf(stderr,
                     "palp: warning: the servo loop missed %.0f %% of its deadlines over 0.8 s and "
                     "gave up at %.2f s: %s, no force rendered from then on (a lighter scene, "
                     "or --servo-cpu on an idle CPU)\n",
                     100 * st.missedFraction, st.overloadedAtSeconds,
                     st.fifoDropped ? "SCHED_FIFO dropped" : "it had no SCHED_FIFO");
    }
    return r;
}

/// Steps @p session offline for @p ticks as fast as possible.
RunResult runFast(haptics::Session& session, std::uint64_t ticks) {
    RunResult r;
    const auto t0 = std::chrono::steady_clock::now();
    // haptics::runOffline's loop, with a progress line on a terminal and a stop on Ctrl-C (what
    // ran so far is kept: the trace, map and summary cover it).
    const InterruptGuard guard;
    const palp::volume::ProgressFn progress = progressLine("palp palpate: simulating");
    r.snaps.reserve(static_cast<std::size_t>(ticks));
    for (std::uint64_t i = 0; i < ticks && !InterruptGuard::interrupted(); ++i) {
        r.snaps.push_back(session.step());
        if (progress && i % 100 == 0) progress(static_cast<double>(i) / static_cast<double>(ticks));
    }
    endProgress();
    r.interrupted = InterruptGuard::signal();
    r.wallSeconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    return r;
}

}  // namespace palp::tool
