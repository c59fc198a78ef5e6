// `palp palpate` as a long run: a progress line on a terminal and none in a pipe, Ctrl-C in the
// middle of an offline run keeps a valid trace and summary of the ticks done, and the MR of the
// shared data (no HU, no bone) palpates deformably.
#include <gtest/gtest.h>
#include <unistd.h>

#include <algorithm>
#include <cstdio>
#include <fstream>
#include <nlohmann/json.hpp>
#include <string>

#include "test_support.h"

namespace {

using palp::test::runCommand;

nlohmann::json jsonOf(const std::string& output) {
    const auto brace = output.find('{'), last = output.rfind('}');
    if (brace == std::string::npos || last < brace) return nlohmann::json::object();
    const auto j = nlohmann::json::parse(output.substr(brace, last - brace + 1), nullptr, false);
    return j.is_discarded() ? nlohmann::json::object() : j;
}

TEST(PalpateRun, ProgressOnATerminalAndNotInAPipe) {
    if (!palp::test::haveProgram("script")) GTEST_SKIP() << "script (util-linux) not installed";
    const std::string cmd =
        palp::test::palpTool().string() + " palpate --phantom bone --fast --seconds 2";
    // script gives the command a pseudo-terminal.
    const auto tty = runCommand("script -qec '" + cmd + "' /dev/null");
    EXPECT_EQ(tty.exitCode, 0) << tty.output;
    EXPECT_NE(tty.output.find("palp palpate: simulating"), std::string::npos) << tty.output;
    const auto pipe = runCommand(cmd + " 2>&1 | cat");
    EXPECT_EQ(pipe.exitCode, 0) << pipe.output;
    EXPECT_EQ(pipe.output.find("simulating"), std::string::npos) << pipe.output;
    EXPECT_NE(pipe.output.find("fast: 2000 ticks"), std::string::npos) << pipe.output;
}

TEST(PalpateRun, CtrlCKeepsAValidTraceAndSummaryOfTheTicksDone) {
    palp::test::TempDir tmp;
    const auto trace = tmp / "t.csv";
    // The whole deformable raster takes minutes offline; SIGINT after 2 s.
    const auto r =
        runCommand("timeout --preserve-status -s INT 2 " + palp::test::palpTool().string() +
                   " palpate --phantom bone --deformable --fast --json --trace " + trace.string() +
                   " 2>" + (tmp / "err.txt").string());
    EXPECT_EQ(r.exitCode, 130) << r.output;  // 128 + SIGINT
    const nlohmann::json j = jsonOf(r.output);
    ASSERT_TRUE(j.contains("ticks")) << r.output;
    EXPECT_TRUE(j["interrupted"].get<bool>());
    const auto ticks = j["ticks"].get<long>();
    EXPECT_GT(ticks, 10);
    EXPECT_LT(ticks, 40000);  // the path's 43,364 were not all run
    // The trace holds a header and one whole row per tick done.
    std::ifstream in(trace);
    ASSERT_TRUE(in.good());
    std::string line, header;
    std::getline(in, header);
    const auto columns = std::count(header.begin(), header.end(), ',');
    long rows = 0;
    while (std::getline(in, line)) {
        EXPECT_EQ(std::count(line.begin(), line.end(), ','), columns) << "row " << rows;
        ++rows;
    }
    EXPECT_EQ(rows, ticks);
    EXPECT_NE(r.output.find("interrupted after " + std::to_string(ticks) + " of"),
              std::string::npos)
        << r.output;
}

// --seconds under --realtime is wall-clock time: the deformable bone phantom's servo loop may
// not keep up on a small machine (it then skips deadlines), and the run still stops after the
// 0.4 s asked for, not after 400 ticks; the ticks run plus the deadlines skipped cover that time.
TEST(PalpateRun, RealtimeSecondsAreWallClockSeconds) {
    const auto r = runCommand(palp::test::palpTool().string() +
                              " palpate --phantom bone --deformable --realtime --seconds 0.4 --json"
                              " 2>/dev/null");
    EXPECT_EQ(r.exitCode, 0) << r.output;
    const nlohmann::json j = jsonOf(r.output);
    ASSERT_TRUE(j.contains("servo")) << r.output;
    const double wall = j["wall_seconds"].get<double>();
    const auto ticks = j["servo"]["ticks"].get<std::uint64_t>();
    const auto skipped = j["servo"]["skipped"].get<std::uint64_t>();
    std::printf("realtime --seconds 0.4: %.3f s wall, %llu ticks, %llu deadlines skipped\n", wall,
                static_cast<unsigned long long>(ticks), static_cast<unsigned long long>(skipped));
    EXPECT_GE(wall, 0.4);
    EXPECT_LT(wall, 0.4 + 1.0);  // the drain's 1 ms polls and stop(): well under a second
    // Periods elapsed: ticks + skipped deadlines, about 400 (+ the last tick's overrun).
    EXPECT_LE(ticks + skipped, 400u + 50u);
    EXPECT_GE(ticks + skipped, 350u);
}

// --mlock locks the process's memory before the servo loop starts and the summary says so: as
// root (CI, and what CAP_IPC_LOCK allows) "memory locked", elsewhere the refusal with its
// reason; without the flag "not asked". The run goes on either way.
TEST(PalpateRun, MlockLocksTheMemoryOrSaysWhyNot) {
    const auto realtimeOf = [](const std::string& flags) {
        const auto r = runCommand(palp::test::palpTool().string() +
                                  " palpate --phantom avc --realtime --seconds 0.2 --json " +
                                  flags + " 2>/dev/null");
        EXPECT_EQ(r.exitCode, 0) << r.output;
        const nlohmann::json j = jsonOf(r.output);
        return j.contains("servo") ? j["servo"]["realtime"].get<std::string>() : std::string();
    };
    const std::string locked = realtimeOf("--mlock");
    std::printf("--mlock: %s\n", locked.c_str());
    if (geteuid() == 0) {
        EXPECT_NE(locked.find("memory locked"), std::string::npos) << locked;
    } else {
        EXPECT_TRUE(locked.find("memory locked") != std::string::npos ||
                    locked.find("mlockall refused: ") != std::string::npos)
            << locked;
    }
    const std::string plain = realtimeOf("");
    EXPECT_NE(plain.find("memory not locked (not asked)"), std::string::npos) << plain;
}

// The overrun budget on a live run that cannot keep up: the bone phantom's whole mesh at 2.5 mm
// cells (32,000 elements, about 12 ms a tick on a 2-vCPU EPYC, so over ten times too slow on any
// machine of today). At SCHED_FIFO the first 0.4 s window misses more than half its deadlines, so
// the loop sheds (VC in place of AVCEC, the tissue frozen in its dent), says so, and then keeps up
// for the rest of the run without giving up its priority; the force stays finite and bounded. A
// SCHED_OTHER loop (FIFO refused) has no budget: it neither sheds nor gives up. --servo-cpu pins
// the loop.
TEST(PalpateRun, AnOverloadedRealtimeRunShedsItsWorkKeepsUpAndSaysSo) {
    const auto r = runCommand(palp::test::palpTool().string() +
                              " palpate --phantom bone --deformable --fem-solver explicit "
                              "--fem-cell-mm 2.5 --realtime --seconds 1.5 --servo-cpu 0 "
                              "--servo-priority 10 --json 2>&1");
    EXPECT_EQ(r.exitCode, 0) << r.output;
    const nlohmann::json j = jsonOf(r.output);
    ASSERT_TRUE(j.contains("servo")) << r.output;
    const auto& s = j["servo"];
    const double ticks = s["ticks"].get<double>(), skipped = s["skipped"].get<double>();
    const std::string rt = s["realtime"].get<std::string>();
    std::printf(
        "realtime 1.5 s: %.0f ticks, %.0f skipped, %d shed at %.3f s, shedding %d, "
        "overloaded %d; %s\n",
        ticks, skipped, s["sheds"].get<int>(), s["shed_at_s"].get<double>(),
        s["shedding"].get<bool>() ? 1 : 0, s["overloaded"].get<bool>() ? 1 : 0, rt.c_str());
    EXPECT_NE(rt.find("pinned to CPU 0"), std::string::npos) << rt;
    EXPECT_LE(j["max_force_n"].get<double>(), 3.3 + 1e-9);
    EXPECT_FALSE(s["overloaded"].get<bool>());
    EXPECT_FALSE(s["fifo_dropped"].get<bool>());
    if (rt.find("SCHED_FIFO 10;") == std::string::npos) {
        EXPECT_EQ(s["sheds"].get<int>(), 0);  // a SCHED_OTHER loop has no budget
        return;
    }
    EXPECT_EQ(s["sheds"].get<int>(), 1);
    EXPECT_TRUE(s["shedding"].get<bool>());  // restoring takes 10 s of calm windows
    EXPECT_EQ(s["restores"].get<int>(), 0);
    // At the end of the first window, plus the ~12 ms tick that crossed it.
    EXPECT_GE(s["shed_at_s"].get<double>(), 0.4);
    EXPECT_LE(s["shed_at_s"].get<double>(), 0.4 + 0.1);
    EXPECT_NE(r.output.find("palp: warning: the servo loop fell behind and shed work 1 time(s)"),
              std::string::npos)
        << r.output;
    // Shed, the loop keeps up: most of the last 1.1 s of deadlines are ticks (un-shed, at 12 ms a
    // tick, it would run under 100 in the whole run).
    EXPECT_GT(ticks, 600);
}

TEST(PalpateRun, TheMrPalpatesDeformablyHeldOnTheFaceOppositeThePress) {
    const auto mr = palp::test::dataPath("nifti-mr");
    if (mr.empty()) GTEST_SKIP() << "no ../shared/data/nifti-mr";
    const auto r = runCommand(palp::test::palpTool().string() + " palpate " +
                              (mr / "anatomical.nii").string() +
                              " --deformable --mode avcec --seconds 3 --json");
    ASSERT_EQ(r.exitCode, 0) << r.output;
    const nlohmann::json j = jsonOf(r.output);
    ASSERT_TRUE(j.contains("deformable")) << r.output;
    // No HU: Otsu's threshold found the head; no bone, so only the support face holds it.
    EXPECT_GT(j["deformable"]["elements"].get<int>(), 500);
    EXPECT_GE(j["deformable"]["pieces_kept"].get<int>(), 1);
    EXPECT_GT(j["contact_fraction_after_approach"].get<double>(), 0.9);
    EXPECT_GE(j["observer_energy_min_j"].get<double>(), 0.0);
    EXPECT_LE(j["max_force_n"].get<double>(), 3.3 + 1e-9);
    EXPECT_TRUE(j["skin"]["following"].get<bool>());
}

}  // namespace
