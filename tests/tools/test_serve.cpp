// `palp serve` with `palp bridge-sim` over loopback: the simulated hand's press is felt (the
// spring chain hand - coupling settles at k_h k / (k_h + k) x the target's depth), every state
// sent is received with none counted lost, the watchdog trips once the hand stops sending; a bad
// --listen address is refused naming it. Ports are the system's choice (--listen 127.0.0.1:0),
// read back from serve's first line, never guessed.
#include <gtest/gtest.h>

#include <fstream>
#include <nlohmann/json.hpp>
#include <sstream>
#include <string>
#include <thread>

#include "serve_address.h"
#include "test_support.h"

namespace {

using palp::test::runCommand;

nlohmann::json readJson(const std::filesystem::path& path) {
    std::ifstream in(path);
    std::stringstream ss;
    ss << in.rdbuf();
    const std::string text = ss.str();
    const auto brace = text.find('{');
    if (brace == std::string::npos) return nlohmann::json::object();
    const auto j = nlohmann::json::parse(text.substr(brace), nullptr, false);
    return j.is_discarded() ? nlohmann::json::object() : j;
}

TEST(Serve, BridgeSimPressIsFeltAndEveryStateCounted) {
    palp::test::TempDir tmp;
    const std::string palp = palp::test::palpTool().string();
    const std::string err = (tmp / "serve.err").string();
    // serve runs 3 s; the hand waits for its answer (set-up), then presses once (1.1 s).
    const auto r = runCommand(palp +
                              " serve --phantom avc --mode vc --k-base 300 --listen 127.0.0.1:0 "
                              "--seconds 3 --json > " +
                              (tmp / "serve.json").string() + " 2> " + err + " & serve=$!; " +
                              palp::test::shellAwaitServeAddress(err) + palp +
                              " bridge-sim --connect $addr --depth 7 --json > " +
                              (tmp / "sim.json").string() + "; s=$?; wait; exit $s");
    ASSERT_EQ(r.exitCode, 0) << r.output;
    const auto serve = readJson(tmp / "serve.json");
    const auto sim = readJson(tmp / "sim.json");
    ASSERT_TRUE(serve.contains("datagrams")) << r.output;
    ASSERT_TRUE(sim.contains("states_sent")) << r.output;
    // The hand connected to the address serve reported, the one it bound.
    EXPECT_EQ(sim["connect"], serve["listen"]);
    EXPECT_NE(serve["listen"].get<std::string>(), "127.0.0.1:0");
    const auto& d = serve["datagrams"];
    const auto sent = sim["states_sent"].get<std::uint64_t>();
    EXPECT_EQ(sent, 1100u);
    // The press's states all arrive; of the handshake's (sent until serve answers), at least the
    // one answered.
    const auto handshake = sim["handshake_states"].get<std::uint64_t>();
    EXPECT_GE(handshake, 1u);
    EXPECT_GE(d["received"].get<std::uint64_t>(), sent + 1);
    EXPECT_LE(d["received"].get<std::uint64_t>(), sent + handshake);
    EXPECT_EQ(d["lost"].get<std::uint64_t>(), 0u);
    EXPECT_EQ(d["late"].get<std::uint64_t>(), 0u);
    EXPECT_EQ(d["ignored"].get<std::uint64_t>(), 0u);
    EXPECT_GE(serve["watchdog"]["trips"].get<std::uint64_t>(), 1u);  // the hand stopped
    EXPECT_TRUE(serve["watchdog"]["stale_at_end"].get<bool>());
    // The faults (docs/architecture.md, "Faults"): stale ticks before the first state and after
    // the hand stopped; the hand's states are all good, and so are the forces.
    const auto& faults = serve["faults"];
    ASSERT_TRUE(faults.is_object()) << serve.dump();
    EXPECT_GT(faults["stale_ticks"].get<std::uint64_t>(), 0u);
    for (const char* none : {"non_finite_states", "out_of_range_states", "too_fast_states",
                             "non_finite_forces", "force_jumps", "session_trips"})
        EXPECT_EQ(faults[none].get<std::uint64_t>(), 0u) << none;
    EXPECT_GT(sim["forces_received"].get<std::uint64_t>(), sent * 9 / 10);
    EXPECT_EQ(sim["forces_lost"].get<std::uint64_t>(), 0u);
    // The hand's target rests 3 mm under the skin (from 4 mm above, 7 mm deep); hand spring
    // 300 N/m in series with the coupling's 300 N/m: 0.45 N while held.
    EXPECT_NEAR(sim["hold_force_mean_n"].get<double>(), 0.45, 0.06);
    EXPECT_NEAR(serve["trace"]["max_force_n"].get<double>(), sim["max_force_n"].get<double>(),
                1e-9);
}

// --servo-cpu and --no-realtime-priority reach the servo thread (its report says so), and the
// summary carries the overrun budget's verdict (a VC phantom keeps up: not overloaded).
TEST(Serve, ServoCpuAndPriorityAreTheOnesAskedFor) {
    const auto r = runCommand(palp::test::palpTool().string() +
                              " serve --phantom avc --mode vc --listen 127.0.0.1:0 --seconds 0.3 "
                              "--servo-cpu 0 --no-realtime-priority --json 2>/dev/null");
    ASSERT_EQ(r.exitCode, 0) << r.output;
    const auto brace = r.output.find('{');
    ASSERT_NE(brace, std::string::npos) << r.output;
    const auto j = nlohmann::json::parse(r.output.substr(brace), nullptr, false);
    ASSERT_FALSE(j.is_discarded()) << r.output;
    const std::string rt = j["servo"]["realtime"].get<std::string>();
    EXPECT_NE(rt.find("pinned to CPU 0"), std::string::npos) << rt;
    EXPECT_NE(rt.find("SCHED_OTHER"), std::string::npos) << rt;
    EXPECT_FALSE(j["servo"]["overloaded"].get<bool>());
    // The servo's CPU is reserved by default (the other threads moved off it, when the process
    // may use another CPU); --servo-share-cpu leaves it shared.
    if (std::thread::hardware_concurrency() > 1) {
        EXPECT_NE(rt.find("other threads moved off it"), std::string::npos) << rt;
    }
    const auto shared = runCommand(palp::test::palpTool().string() +
                                   " serve --phantom avc --mode vc --listen 127.0.0.1:0 "
                                   "--seconds 0.2 --servo-cpu 0 --no-realtime-priority "
                                   "--servo-share-cpu --json 2>/dev/null");
    ASSERT_EQ(shared.exitCode, 0) << shared.output;
    const auto js = nlohmann::json::parse(shared.output.substr(shared.output.find('{')));
    const std::string rs = js["servo"]["realtime"].get<std::string>();
    EXPECT_NE(rs.find("pinned to CPU 0"), std::string::npos) << rs;
    EXPECT_EQ(rs.find("moved off"), std::string::npos) << rs;
    const auto both = runCommand(palp::test::palpTool().string() +
                                 " serve --phantom avc --servo-priority 10 --no-realtime-priority");
    EXPECT_NE(both.exitCode, 0);
    EXPECT_NE(both.output.find("excludes"), std::string::npos) << both.output;
}

TEST(Serve, BadListenAddressIsRefusedByName) {
    const auto r = runCommand(palp::test::palpTool().string() +
                              " serve --phantom avc --listen localhost7405 --seconds 1");
    EXPECT_NE(r.exitCode, 0);
    EXPECT_NE(r.output.find("palp: error: --listen 'localhost7405': expected host:port"),
              std::string::npos)
        << r.output;
}

TEST(Serve, PortInUseIsRefusedNamingListen) {
    palp::test::TempDir tmp;
    const std::string err = (tmp / "first.err").string();
    const std::string palp = palp::test::palpTool().string();
    const std::string serve = " serve --phantom avc --seconds 1 --listen ";
    // The second serve binds the address the first one was given by the system (which it
    // reports even with --quiet: nobody could know it otherwise).
    const auto r =
        runCommand(palp + " --quiet" + serve + "127.0.0.1:0 >/dev/null 2> " + err +
                   " & serve=$!; " + palp::test::shellAwaitServeAddress(err) +
                   "echo \"first on $addr\"; " + palp + serve + "$addr 2>&1; s=$?; wait; exit $s");
    EXPECT_NE(r.exitCode, 0);
    const std::string first = "first on ";
    const auto at = r.output.find(first);
    ASSERT_NE(at, std::string::npos) << r.output;
    const std::string address =
        r.output.substr(at + first.size(), r.output.find('\n', at) - at - first.size());
    EXPECT_EQ(address.rfind("127.0.0.1:", 0), 0u) << address;
    EXPECT_NE(address, "127.0.0.1:0");
    EXPECT_NE(r.output.find("palp: error: --listen " + address +
                            ": cannot bind: Address already in use (EADDRINUSE)"),
              std::string::npos)
        << r.output;
}

}  // namespace
