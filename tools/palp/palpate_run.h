#pragma once
/// @file
/// `palp palpate`'s run: offline as fast as possible or on the real-time servo loop, with a
/// progress line on a terminal and a stop on Ctrl-C that keeps what ran.

#include <cstdint>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "palp/haptics/session.h"

namespace palp::tool {

/// The snapshots of a run and, in real time, the servo's figures.
struct RunResult {
    std::vector<haptics::Snapshot> snaps;
    double wallSeconds = 0;
    std::string loopText;
    nlohmann::json loopJson;
    std::uint64_t traceDropped = 0;  // real time: ticks the trace ring could not hold
    int interrupted = 0;             // the signal (Ctrl-C: SIGINT) that stopped the run early
};

/// Runs @p session on its servo thread (or until Ctrl-C), draining every tick's snapshot: for
/// @p wallSeconds of wall-clock time from the start when it is > 0 (`--seconds` under
/// `--realtime`: an overloaded loop that skips deadlines runs fewer ticks, never longer), else
/// until @p ticks ticks have run (the simulated hand's path is done: its time is counted in
/// ticks).
RunResult runRealtime(haptics::Session& session, std::uint64_t ticks, double wallSeconds = 0);
/// Steps @p session offline for @p ticks (or until Ctrl-C).
RunResult runFast(haptics::Session& session, std::uint64_t ticks);

}  // namespace palp::tool
