// palp bridge-sim: a simulated remote device for `palp serve`: a hand (mass-spring-damper) that
// presses along an axis again and again, sends its state over UDP at the servo rate and feels
// the force that comes back; reports the datagrams and the round trip as JSON.
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <memory>
#include <nlohmann/json.hpp>
#include <optional>
#include <string>
#include <thread>
#include <vector>

#include "commands.h"
#include "option_checks.h"
#include "palp/base/bounds.h"
#include "palp/base/error.h"
#include "palp/base/validate.h"
#include "palp/haptics/devices/simulated_device.h"
#include "palp/haptics/devices/trajectory.h"
#include "palp/haptics/devices/udp_bridge_client.h"

namespace palp::tool {

using nlohmann::json;

namespace {

struct SimArgs {
    std::string connect = "127.0.0.1:7405";
    std::vector<double> fromMm{4, -4, 3};
    std::vector<double> orientation{1, 0, 0, 0};  ///< w, x, y, z
    std::string axis = "+y";
    double depthMm = 7;
    double pressSeconds = 0.3;
    double holdSeconds = 0.4;
    double restSeconds = 0.1;
    double seconds = 0;  ///< 0: one press
    double rateHz = 1000;
    double waitSeconds = 5;
    std::string device = "3D Systems Touch";
    bool json = false;
};

double quantile(std::vector<double>& v, double q) {
    if (v.empty()) return 0;
    const auto k = static_cast<std::size_t>(q * static_cast<double>(v.size() - 1));
    std::nth_element(v.begin(), v.begin() + static_cast<std::ptrdiff_t>(k), v.end());
    return v[k];
}

std::uint64_t nowNs() {
    return static_cast<std::uint64_t>(std::chrono::duration_cast<std::chrono::nanoseconds>(
                                          std::chrono::steady_clock::now().time_since_epoch())
                                          .count());
}

int runBridgeSim(const SimArgs& a) {
    const haptics::DeviceSpec* spec = haptics::findDeviceSpec(a.device);
    if (!spec)
        throw ValueError("--device: expected a device class of palp's table, found '" + a.device +
                         "'");
    const double period = 1.0 / a.rateHz;
    haptics::PressTrajectory press;
    press.start = Eigen::Vector3d(a.fromMm[0], a.fromMm[1], a.fromMm[2]) * 1e-3;
    press.direction = parseAxis(a.axis, "--axis");
    press.depthM = a.depthMm * 1e-3;
    press.pressSeconds = a.pressSeconds;
    press.holdSeconds = a.holdSeconds;
    const double cycle = 2 * a.pressSeconds + a.holdSeconds + a.restSeconds;
    const double total = a.seconds > 0 ? a.seconds : cycle;
    const auto samples = static_cast<std::uint64_t>(std::ceil(total / period));
    const auto cycleSamples =
        std::max<std::uint64_t>(1, static_cast<std::uint64_t>(std::llround(cycle / period)));

    const Eigen::Quaterniond given(a.orientation[0], a.orientation[1], a.orientation[2],
                                   a.orientation[3]);
    if (!(given.norm() > 1e-9)) {
        throw ValueError(
            "--orientation: expected a quaternion w,x,y,z of non-zero norm, found "
            "0,0,0,0");
    }
    const Eigen::Quaterniond q = given.normalized();
    haptics::UdpBridgeClient client(a.connect);
    // Handshake: the start position every 10 ms until a force answers (palp serve may still be
    // building its scene), so that the press itself starts with the session listening.
    std::uint64_t sequence = 0, handshake = 0;
    {
        const auto w0 = std::chrono::steady_clock::now();
        haptics::bridge::ForceMessage f;
        for (;;) {
            haptics::bridge::StateMessage m;
            m.sequence = ++sequence;
            m.timeNs = nowNs();
            m.position = press.start;
            m.orientation = q;
            client.send(m);
            ++handshake;
            if (client.receive(f, 0.01)) break;
            if (std::chrono::duration<double>(std::chrono::steady_clock::now() - w0).count() >
                a.waitSeconds) {
                throw IoError(a.connect + ": expected palp serve to answer within " +
                              formatValue(a.waitSeconds) + " s (--wait), found no answer");
            }
        }
        while (client.receive(f, 0)) {
        }
    }
    std::optional<haptics::SimulatedDevice> hand;
    std::vector<double> roundTripUs;
    roundTripUs.reserve(static_cast<std::size_t>(samples));
    std::vector<double> transitUs;  // palp's sending to our receipt (one clock on one host)
    transitUs.reserve(static_cast<std::size_t>(samples) + 64);
    std::uint64_t sent = 0, sendFailed = 0, forces = 0, forcesLost = 0, stale = 0, cut = 0;
    std::uint64_t lastForceSequence = 0, lastTick = 0, lastEchoed = 0;
    double maxForce = 0, holdForceSum = 0;
    std::uint64_t holdForces = 0;
    Eigen::Vector3d force = Eigen::Vector3d::Zero();
    const auto t0 = std::chrono::steady_clock::now();
    for (std::uint64_t i = 0; i < samples; ++i) {
        const std::uint64_t inCycle = i % cycleSamples;
        if (inCycle == 0) hand.emplace(*spec, press, haptics::HandModel{}, period);
        hand->write(force);
        const haptics::DeviceState ds = hand->read();
        haptics::bridge::StateMessage m;
        m.sequence = ++sequence;
        m.timeNs = nowNs();
        m.position = ds.position;
        m.velocity = ds.velocity;
        m.buttons = ds.buttons;
        m.orientation = q;
        if (client.send(m)) {
            ++sent;
        } else {
            ++sendFailed;
        }
        const double t = static_cast<double>(inCycle) * period;
        const bool holding = t > a.pressSeconds + 0.1 && t < a.pressSeconds + a.holdSeconds;
        // Take every force that arrives until the next sample is due (the round trip is timed
        // when each arrives).
        const auto next =
            t0 + std::chrono::duration_cast<std::chrono::steady_clock::duration>(
                     std::chrono::duration<double>(period * static_cast<double>(i + 1)));
        for (;;) {
            const double left =
                std::chrono::duration<double>(next - std::chrono::steady_clock::now()).count();
            haptics::bridge::ForceMessage f;
            if (!client.receive(f, std::max(0.0, left))) break;
            ++forces;
            transitUs.push_back(static_cast<double>(static_cast<std::int64_t>(nowNs() - f.timeNs)) *
                                1e-3);
            // The round trip of a state: from its sending to the first force computed from it
            // (the servo's next tick, then the way back).
            if (f.stateSequence != lastEchoed && f.stateTimeNs > 0)
                roundTripUs.push_back(static_cast<double>(nowNs() - f.stateTimeNs) * 1e-3);
            if (lastForceSequence > 0 && f.sequence > lastForceSequence + 1)
                forcesLost += f.sequence - lastForceSequence - 1;
            lastForceSequence = std::max(lastForceSequence, f.sequence);
            lastTick = f.tick;
            lastEchoed = f.stateSequence;
            stale += (f.flags & haptics::bridge::kForceStale) ? 1 : 0;
            cut += (f.flags & haptics::bridge::kForceCut) ? 1 : 0;
            force = f.force;
            maxForce = std::max(maxForce, f.force.norm());
            if (holding) {
                holdForceSum += f.force.norm();
                ++holdForces;
            }
        }
    }
    const double wall =
        std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    json j;
    j["connect"] = a.connect;
    j["seconds"] = wall;
    j["rate_hz"] = a.rateHz;
    j["presses"] = (samples + cycleSamples - 1) / cycleSamples;
    j["handshake_states"] = handshake;
    j["states_sent"] = sent;
    j["states_send_failed"] = sendFailed;
    j["forces_received"] = forces;
    j["forces_lost"] = forcesLost;
    j["forces_stale"] = stale;
    j["forces_cut"] = cut;
    j["last_tick"] = lastTick;
    j["max_force_n"] = maxForce;
    j["hold_force_mean_n"] = holdForces ? holdForceSum / static_cast<double>(holdForces) : 0.0;
    j["round_trip_us"] = {
        {"p50", quantile(roundTripUs, 0.5)},
        {"p99", quantile(roundTripUs, 0.99)},
        {"max",
         roundTripUs.empty() ? 0.0 : *std::max_element(roundTripUs.begin(), roundTripUs.end())},
        {"count", roundTripUs.size()}};
    // On one host palp's CLOCK_MONOTONIC is ours (steady_clock): the way back alone.
    j["force_transit_us_same_host"] = {{"p50", quantile(transitUs, 0.5)},
                                       {"p99", quantile(transitUs, 0.99)}};
    if (a.json) {
        std::printf("%s\n", j.dump(2).c_str());
    } else if (!globals().quiet) {
        std::printf(
            "palp bridge-sim: %llu states sent, %llu forces back (%llu lost, %llu stale); round "
            "trip p50 %.0f us, p99 %.0f us; max force %.3f N, mean while held %.3f N\n",
            static_cast<unsigned long long>(sent), static_cast<unsigned long long>(forces),
            static_cast<unsigned long long>(forcesLost), static_cast<unsigned long long>(stale),
            j["round_trip_us"]["p50"].get<double>(), j["round_trip_us"]["p99"].get<double>(),
            maxForce, j["hold_force_mean_n"].get<double>());
    }
    if (forces == 0) {
        throw IoError(a.connect +
                      ": expected forces back from palp serve, found none (is it "
                      "listening there?)");
    }
    return 0;
}

}  // namespace

Command addBridgeSim(CLI::App& root) {
    auto args = std::make_shared<SimArgs>();
    CLI::App* app = root.add_subcommand(
        "bridge-sim",
        "A simulated remote device for `palp serve`: a hand that presses along an axis, sends "
        "its state over UDP at the servo rate and feels the force that comes back");
    SimArgs& a = *args;
    app->add_option("--connect", a.connect,
                    "Address of palp serve, host:port (default "
                    "127.0.0.1:7405)");
    app->add_option("--from", a.fromMm,
                    "Where each press starts x,y,z, mm (device frame; default 4,-4,3: 4 mm "
                    "above the avc phantom's skin)")
        ->delimiter(',')
        ->expected(3)
        ->check(within(bounds::kPosition, kMm));
    app->add_option("--axis", a.axis, "Press direction (default +y)");
    app->add_option("--orientation", a.orientation,
                    "The hand's orientation sent with every state, quaternion w,x,y,z (default "
                    "1,0,0,0)")
        ->delimiter(',')
        ->expected(4)
        ->check(within({-1e3, 1e3, ""}));
    app->add_option("--depth", a.depthMm, "How far the hand's target moves, mm (default 7)")
        ->check(within(bounds::kLength, kMm));
    app->add_option("--press-seconds", a.pressSeconds, "Time to press in (and out), s (0.3)")
        ->check(within(bounds::kPositiveDuration));
    app->add_option("--hold", a.holdSeconds, "Hold time, s (0.4)")
        ->check(within(bounds::kDuration));
    app->add_option("--rest", a.restSeconds, "Rest between presses, s (0.1)")
        ->check(within(bounds::kDuration));
    app->add_option("--seconds", a.seconds, "Press again and again this long, s (default: one)")
        ->check(within(bounds::kDuration));
    app->add_option("--rate", a.rateHz, "States per second (default 1000)")
        ->check(within(bounds::kPositiveFrequency));
    app->add_option("--device", a.device, "Device class whose force limit the hand feels");
    app->add_option("--wait", a.waitSeconds,
                    "Wait this long for palp serve to answer before pressing, s (default 5)")
        ->check(within(bounds::kPositiveDuration));
    app->add_flag("--json", a.json, "Print the figures as JSON");
    return {app, [args]() -> int { return runBridgeSim(*args); }};
}

}  // namespace palp::tool
