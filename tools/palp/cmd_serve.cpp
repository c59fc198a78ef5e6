// palp serve: runs a session on the 1 kHz servo loop for a remote device that speaks the bridge
// protocol over UDP (docs/device_bridge.md), for --seconds or until SIGINT, and prints what
// happened as JSON (datagrams, watchdog, loop figures, forces).
#include <atomic>
#include <chrono>
#include <cmath>
#include <csignal>
#include <cstdio>
#include <limits>
#include <memory>
#include <nlohmann/json.hpp>
#include <optional>
#include <string>
#include <thread>
#include <vector>

#include "batch_heap.h"
#include "commands.h"
#include "option_checks.h"
#include "palp/base/bounds.h"
#include "palp/base/error.h"
#include "palp/base/validate.h"
#include "palp/haptics/devices/udp_device.h"
#include "palp/haptics/session.h"
#include "palpate_options.h"
#include "palpate_setup.h"

#ifdef PALP_HAVE_OPENIGTLINK
#include "igtl_stream.h"
#endif

namespace palp::tool {

using nlohmann::json;

namespace {

struct ServeArgs {
    PalpateArgs scene;  ///< FILE / --phantom and the coupling options, as palpate reads them
    std::string listen = "127.0.0.1:7405";
    double seconds = 0;
    std::vector<double> offsetMm;
    double scale = 1;
    double watchdogMs = 10;
    double graceMs = 2;
    int igtlPort = -1;  ///< -1: no OpenIGTLink stream; 0: any free TCP port
    double igtlRateHz = 30;
    bool json = false;
    ServoArgs servo;
};

std::atomic<bool> gInterrupted{false};
extern "C" void onInterrupt(int) { gInterrupted.store(true); }

/// SIGINT and SIGTERM set gInterrupted while this lives; the old handlers come back after.
class InterruptGuard {
  public:
    InterruptGuard() {
        struct sigaction sa {};
        sa.sa_handler = onInterrupt;
        sigemptyset(&sa.sa_mask);
        sigaction(SIGINT, &sa, &mOldInt);
        sigaction(SIGTERM, &sa, &mOldTerm);
    }
    ~InterruptGuard() {
        sigaction(SIGINT, &mOldInt, nullptr);
        sigaction(SIGTERM, &mOldTerm, nullptr);
    }
    InterruptGuard(const InterruptGuard&) = delete;
    InterruptGuard& operator=(const InterruptGuard&) = delete;

  private:
    struct sigaction mOldInt {};
    struct sigaction mOldTerm {};
};

json countersJson(const haptics::UdpDeviceCounters& c) {
    return {{"received", c.received},
            {"superseded", c.superseded},
            {"lost", c.lost},
            {"late", c.late},
            {"restarts", c.restarts},
            {"peer_changes", c.peerChanges},
            {"ignored", c.ignored()},
            {"ignored_by_reason",
             {{"short", c.shortDatagrams},
              {"bad_magic", c.badMagic},
              {"bad_version", c.badVersion},
              {"bad_type", c.badType},
              {"bad_size", c.badSize}}},
            {"receive_errors", c.receiveErrors},
            {"drain_limited", c.drainLimited},
            {"forces_sent", c.sent},
            {"forces_send_failed", c.sendFailed}};
}

json loopJson(const haptics::ServoStats& st, const haptics::RealtimeStatus& rs) {
    const auto us = [](const haptics::LatencySummary& l) {
        return json{{"p50", l.p50 * 1e6}, {"p99", l.p99 * 1e6}, {"max", l.max * 1e6}};
    };
    return {{"ticks", st.ticks},
            {"misses", st.misses},
            {"skipped", st.skipped},
            {"wake_latency_us", us(st.wakeLatency)},
            {"compute_us", us(st.compute)},
            {"overloaded", st.overloaded},
            {"fifo_dropped", st.fifoDropped},
            {"overloaded_at_s", st.overloadedAtSeconds},
            {"overloaded_missed_fraction", st.missedFraction},
            {"shedding", st.shedding},
            {"sheds", st.sheds},
            {"restores", st.restores},
            {"shed_at_s", st.shedAtSeconds},
            {"realtime", rs.message}};
}

/// Ticks with each fault (DeviceFault; docs/architecture.md, "Faults"), the session's fault
/// ramp's trips and the ticks with any fault among those the trace held.
json faultsJson(const haptics::Snapshot& last, std::uint64_t faultTicks) {
    const haptics::FaultCounts& c = last.faultCounts;
    return {{"stale_ticks", c.stale},
            {"non_finite_states", c.nonFinite},
            {"out_of_range_states", c.outOfRange},
            {"too_fast_states", c.tooFast},
            {"non_finite_forces", c.forceNonFinite},
            {"force_jumps", c.forceJump},
            {"overload_ticks", c.overload},
            {"shed_ticks", c.shed},
            {"session_trips", last.faultTrips},
            {"traced_ticks_with_a_fault", faultTicks}};
}

int runServe(ServeArgs& a) {
    liveHeap();
    const PalpateArgs& pa = a.scene;
    if (pa.file.empty() == pa.phantom.empty()) {
        throw ValueError("serve: expected a FILE or --phantom SCENE, found " +
                         std::string(pa.file.empty() ? "neither" : "both"));
    }
    const haptics::DeviceSpec* spec = haptics::findDeviceSpec(pa.device);
    if (!spec) {
        std::string names;
        for (const auto& s : haptics::deviceSpecs())
            names += (names.empty() ? "'" : ", '") + std::string(s.name) + "'";
        throw ValueError("--device: expected one of " + names + ", found '" + pa.device + "'");
    }
    if (!(a.graceMs < a.watchdogMs)) {
        throwExpected("--watchdog-grace-ms",
                      "less than --watchdog-ms (" + formatValue(a.watchdogMs) + " ms)",
                      formatValue(a.graceMs) + " ms");
    }
    const double period = 1e-3;
#ifndef PALP_HAVE_OPENIGTLINK
    if (a.igtlPort >= 0) {
        throw ValueError(
            "--igtl-port: expected a palp built with OpenIGTLink "
            "(libopenigtlink-dev), found one built without it");
    }
#endif

    // The socket first: a port in use fails at once, before the scene is built.
    haptics::UdpDeviceParams dp;
    dp.listen = a.listen;
    dp.periodSeconds = period;
    dp.watchdog.timeoutSeconds = a.watchdogMs * 1e-3;
    dp.watchdog.graceSeconds = a.graceMs * 1e-3;
    // The library names its field; the command line says --listen.
    std::optional<haptics::UdpDevice> remote;
    namingOption("udp device listen address", "--listen", [&] { remote.emplace(*spec, dp); });
    haptics::UdpDevice& device = *remote;
    // The bound address first, on a line of its own (the port the system chose for port 0), so
    // that a script or a test can connect to it: printed even with --quiet when it was chosen.
    const bool portChosen = haptics::parseUdpEndpoint(a.listen, "--listen").port == 0;
    if (!globals().quiet || portChosen) {
        std::fprintf(stderr, "palp serve: listening on udp %s\n", device.address().c_str());
        std::fflush(stderr);
    }

    Input in = loadInput(pa);
    haptics::CouplingParams cp = couplingFromOptions(pa, in.cp);
    haptics::validateCouplingParams(cp);
    const double kMaxAsked = cp.maxStiffness;
    haptics::limitStiffnessToDevice(cp, *spec, period);
    haptics::SceneOptions so;
    so.surfaceIso = pa.surfaceIso;
    if (cp.source == haptics::RaySource::Mesh) so.hardIso = cp.firstHit.threshold;
    auto scene = haptics::Scene::fromVolume(in.vol, so);

    haptics::SessionParams sp;
    sp.coupling = cp;
    sp.proxy.staticFriction = pa.muStatic;
    sp.proxy.dynamicFriction =
        std::isfinite(pa.muDynamic) ? pa.muDynamic : std::min(0.3, pa.muStatic);
    sp.passivityControl = pa.passivityControl;
    sp.servo.periodSeconds = period;
    a.servo.applyTo(sp.servo);
    sp.workspace.scale = a.scale;
    if (a.offsetMm.size() == 3)
        sp.workspace.offset = Eigen::Vector3d(a.offsetMm[0], a.offsetMm[1], a.offsetMm[2]) * 1e-3;
    sp.traceCapacity = 1u << 14;
    haptics::validateSessionParams(sp);

    haptics::Session session(scene, device, sp);

    if (!globals().quiet) {
        std::fprintf(stderr, "palp serve: %s, %s/%s on %s%s\n", in.label.c_str(),
                     haptics::couplingModeName(cp.mode), haptics::raySourceName(cp.source),
                     std::string(spec->name).c_str(), a.seconds > 0 ? "" : " (Ctrl-C to stop)");
    }
#ifdef PALP_HAVE_OPENIGTLINK
    // The stream's thread is the session's viewer (latest()); this thread reads the trace.
    std::optional<IgtlStream> igtl;
    if (a.igtlPort >= 0) {
        // The device's orientation (not in a Snapshot) from its published state, in the world.
        const Eigen::Matrix3d worldFromDeviceFrame = sp.workspace.rotation;
        igtl.emplace(session, a.igtlPort, a.igtlRateHz, [&device, worldFromDeviceFrame] {
            const Eigen::Quaterniond q = device.publishedState().orientation;
            const double n = q.norm();
            if (!(n > 0.5 && n < 2)) return worldFromDeviceFrame;  // none, or not a rotation
            return Eigen::Matrix3d(worldFromDeviceFrame * q.normalized().toRotationMatrix());
        });
        if (!globals().quiet || a.igtlPort == 0) {
            std::fprintf(stderr, "palp serve: igtl on tcp %d\n", igtl->port());
            std::fflush(stderr);
        }
    }
#endif
    InterruptGuard guard;
    gInterrupted.store(false);
    const auto t0 = std::chrono::steady_clock::now();
    session.start();
    // The trace ring is drained here (never by the servo thread) for the summary's figures.
    std::uint64_t ticks = 0, contact = 0, faulted = 0, clamped = 0, faultTicks = 0;
    double maxForce = 0;
    haptics::Snapshot s;
    const auto drain = [&] {
        while (session.popTrace(s)) {
            ++ticks;
            contact += s.contactCount > 0 ? 1 : 0;
            faulted += s.faulted ? 1 : 0;
            clamped += s.clamped ? 1 : 0;
            faultTicks += s.faultFlags != 0 ? 1 : 0;
            maxForce = std::max(maxForce, s.force.norm());
        }
    };
    const auto elapsed = [&] {
        return std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    };
    while (!gInterrupted.load() && (a.seconds <= 0 || elapsed() < a.seconds)) {
        drain();
        std::this_thread::sleep_for(std::chrono::milliseconds(10));
    }
    session.stop();
    drain();
    const double wall = elapsed();
    json igtlJson;
#ifdef PALP_HAVE_OPENIGTLINK
    if (igtl) {
        igtlJson = {{"port", igtl->port()},
                    {"rate_hz", a.igtlRateHz},
                    {"clients", igtl->clients()},
                    {"frames", igtl->framesSent()}};
        igtl.reset();  // joined: latest() is this thread's again
    }
#endif
    const haptics::Snapshot& last = session.latest();

    json j;
    j["input"] = in.label;
    j["listen"] = device.address();
    j["device"] = std::string(spec->name);
    j["mode"] = haptics::couplingModeName(cp.mode);
    j["source"] = haptics::raySourceName(cp.source);
    j["k_base_npm"] = cp.baseStiffness;
    j["k_max_npm"] = cp.maxStiffness;
    j["k_max_asked_npm"] = kMaxAsked;
    j["seconds"] = wall;
    j["stopped_by"] = gInterrupted.load() ? "signal" : "--seconds";
    j["datagrams"] = countersJson(device.counters());
    j["watchdog"] = {{"timeout_ms", a.watchdogMs},
                     {"grace_ms", a.graceMs},
                     {"trips", last.watchdogTrips},
                     {"stale_at_end", last.deviceStale}};
    j["faults"] = faultsJson(last, faultTicks);
    j["servo"] = loopJson(session.stats(), session.realtime());
    if (!igtlJson.is_null()) j["igtl"] = igtlJson;
    j["trace"] = {{"ticks", ticks},
                  {"dropped", session.traceDropped()},
                  {"contact_fraction",
                   ticks ? static_cast<double>(contact) / static_cast<double>(ticks) : 0.0},
                  {"max_force_n", maxForce},
                  {"faulted_ticks", faulted},
                  {"clamped_ticks", clamped}};
    if (a.json) {
        std::printf("%s\n", j.dump(2).c_str());
    } else if (!globals().quiet) {
        const haptics::UdpDeviceCounters c = device.counters();
        std::printf(
            "palp serve: %.1f s, %llu ticks; %llu states received (%llu lost, %llu late, %llu "
            "ignored), %llu forces sent; watchdog trips %llu; last good force held %llu ticks "
            "(states non-finite %llu, out of range %llu, too fast %llu); max force %.3f N\n",
            wall, static_cast<unsigned long long>(ticks),
            static_cast<unsigned long long>(c.received), static_cast<unsigned long long>(c.lost),
            static_cast<unsigned long long>(c.late), static_cast<unsigned long long>(c.ignored()),
            static_cast<unsigned long long>(c.sent),
            static_cast<unsigned long long>(last.watchdogTrips),
            static_cast<unsigned long long>(last.faults),
            static_cast<unsigned long long>(last.faultCounts.nonFinite),
            static_cast<unsigned long long>(last.faultCounts.outOfRange),
            static_cast<unsigned long long>(last.faultCounts.tooFast), maxForce);
    }
    return 0;
}

}  // namespace

Command addServe(CLI::App& root) {
    auto args = std::make_shared<ServeArgs>();
    CLI::App* app = root.add_subcommand(
        "serve",
        "Run a session on the 1 kHz servo loop for a remote device that sends its state over UDP "
        "(bridge protocol, docs/device_bridge.md) and receives the force back; print a summary");
    ServeArgs& a = *args;
    PalpateArgs& p = a.scene;
    app->add_option("file", p.file, "Volume to palpate (.vdb or any scan palp reads)");
    app->add_option("--phantom", p.phantom, "Built-in scene instead of a file")
        ->check(CLI::IsMember({"avc", "avcec", "bone", "stiffness", "tumour"}));
    app->add_option("--voxel-mm", p.voxelMm, "Phantom voxel edge, mm (default 1)")
        ->check(within(bounds::kSpacing, kMm));
    app->add_option("--listen", a.listen,
                    "UDP address to receive states on, host:port (default "
                    "127.0.0.1:7405; port 0: any free one, printed)");
    app->add_option("--seconds", a.seconds, "Run this long, s (default: until Ctrl-C)")
        ->check(within(bounds::kPositiveDuration));
    app->add_option("--mode", p.mode, "Coupling: vc, avc or avcec (default per scene)");
    app->add_option("--source", p.source,
                    "Ray source: mesh, first-hit or accumulate (default per scene)");
    app->add_option("--k-base", p.kBase, "Surface stiffness k_s, N/m (default 300)")
        ->check(within(bounds::kPositiveStiffness));
    app->add_option("--k-max", p.kMax,
                    "Stiffness clamp k_max, N/m (default 2400, lowered to the device's limit)")
        ->check(within(bounds::kPositiveStiffness));
    app->add_option("--damping", p.damping, "Coupling damping b, N s/m (default 0)")
        ->check(within(bounds::kDamping));
    app->add_option("--mu-static", p.muStatic, "Static friction (default 0.5)")
        ->check(within(bounds::kFriction));
    app->add_option("--surface-iso", p.surfaceIso,
                    "Value of the surface the proxy slides on (default -500 HU)")
        ->check(within(bounds::kVolumeValue, {1, "HU"}));
    app->add_flag("--passivity-control", p.passivityControl,
                  "Add the passivity controller (the observer always runs)");
    app->add_option("--device", p.device,
                    "Device class of the remote device, whose limits apply (default '3D "
                    "Systems Touch')");
    app->add_option("--offset", a.offsetMm,
                    "World position of the device's origin x,y,z, mm (default 0,0,0)")
        ->delimiter(',')
        ->expected(3)
        ->check(within(bounds::kPosition, kMm));
    app->add_option("--scale", a.scale, "World metres per device metre (default 1)")
        ->check(within(bounds::kScale));
    app->add_option("--watchdog-ms", a.watchdogMs,
                    "No fresh state for this long: zero force, ms (default 10)")
        ->check(within({0, 10, "s", true}, {1e3, "ms"}));
    app->add_option("--watchdog-grace-ms", a.graceMs,
                    "No fresh state for up to this long: force kept whole, ms (default 2)")
        ->check(within({0, 10, "s"}, {1e3, "ms"}));
    app->add_option("--igtl-port", a.igtlPort,
                    "Serve an OpenIGTLink v2 stream on this TCP port (Slicer, MITK): TRANSFORM "
                    "ProxyToRAS and DeviceToRAS (RAS mm), SENSOR Force (N) (default: none; 0: "
                    "any free port, printed)")
        ->check(integerIn(0, 65535));
    app->add_option("--igtl-rate", a.igtlRateHz, "OpenIGTLink frames per second (default 30)")
        ->check(within({0, 200, "Hz", true}));
    addServoOptions(app, a.servo);
    app->add_flag("--json", a.json, "Print the summary as JSON");
    return {app, [args]() -> int { return runServe(*args); }};
}

}  // namespace palp::tool
