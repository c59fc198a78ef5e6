// bench_soak: a live session left running (issue 38's soak). Each scene runs on the real servo
// thread (SCHED_FIFO where allowed) for --seconds, and every --window seconds the program notes
// the resident set, the allocations the servo thread made, the ticks' compute time and period
// error in that window (quantiles), the loop's misses and skips, the largest force and any
// fault. Scenes: the bone phantom rigid (AVCEC on the volume) and deformable (the tool's tissue
// defaults), both with a simulated hand circling on the skin, and the rigid scene driven over
// the UDP bridge by a remote device on another thread of this process (a circle sent at 1 kHz,
// the forces read back). With --check it exits 1 when a window after the first allocates on
// the servo thread, the resident set's lowest value in the run's second half is over 1 % above
// that of its first (the first window is warm-up), a force is not finite or above the device's
// maximum, the loop's tick count disagrees with the ticks the device saw, the loop gave up (overrun
// budget), or no state reached the session over the bridge. Timing is reported, never checked
// (bench/README.md, "Soak").
//
//   bench_soak [--scene rigid|deformable|udp|all] [--seconds S] [--window W] [--check]
//              [--servo-cpu N] [--servo-priority P] [--fem-solver auto|explicit|regions]
//              [--json FILE]
#include <malloc.h>
#include <time.h>
#include <unistd.h>

#include <CLI/CLI.hpp>
#include <algorithm>
#include <array>
#include <atomic>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <fstream>
#include <memory>
#include <nlohmann/json.hpp>
#include <string>
#include <thread>
#include <vector>

#include "alloc_counter.h"
#include "palp/haptics/devices/simulated_device.h"
#include "palp/haptics/devices/trajectory.h"
#include "palp/haptics/devices/udp_bridge_client.h"
#include "palp/haptics/devices/udp_device.h"
#include "palp/haptics/rendering/coupling_defaults.h"
#include "palp/haptics/session.h"
#include "palp/haptics/tissue/deformable_setup.h"
#include "palp/volume/phantom.h"

namespace {

using namespace palp;
using namespace palp::haptics;
using json = nlohmann::json;

constexpr double kPeriod = 1e-3;

std::int64_t nowNs() noexcept {
    timespec ts{};
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return static_cast<std::int64_t>(ts.tv_sec) * 1'000'000'000 + ts.tv_nsec;
}

/// 1 us bins up to 20 ms (the last bin takes everything longer); the servo thread adds, the
/// main thread copies. Relaxed atomics: a window's copy may miss the tick in flight.
class Histogram {
  public:
    static constexpr std::size_t kBins = 20'001;
    void add(std::int64_t ns) noexcept {
        const auto us = static_cast<std::size_t>(std::max<std::int64_t>(ns, 0) / 1000);
        mBins[std::min(us, kBins - 1)].fetch_add(1, std::memory_order_relaxed);
    }
    std::vector<std::uint64_t> copy() const {
        std::vector<std::uint64_t> out(kBins);
        for (std::size_t i = 0; i < kBins; ++i) out[i] = mBins[i].load(std::memory_order_relaxed);
        return out;
    }

  private:
    std::array<std::atomic<std::uint64_t>, kBins> mBins{};
};

/// Quantile @p q of the counts (bin upper edges), ms.
double quantileMs(const std::vector<std::uint64_t>& counts, double q) {
    std::uint64_t total = 0;
    for (auto c : counts) total += c;
    if (total == 0) return 0;
    const auto want = static_cast<std::uint64_t>(std::ceil(q * static_cast<double>(total)));
    std::uint64_t seen = 0;
    for (std::size_t i = 0; i < counts.size(); ++i) {
        seen += counts[i];
        if (seen >= std::max<std::uint64_t>(want, 1)) return 1e-3 * static_cast<double>(i + 1);
    }
    return 1e-3 * static_cast<double>(counts.size());
}

std::vector<std::uint64_t> minus(const std::vector<std::uint64_t>& a,
                                 const std::vector<std::uint64_t>& b) {
    std::vector<std::uint64_t> d(a.size());
    for (std::size_t i = 0; i < a.size(); ++i) d[i] = a[i] - b[i];
    return d;
}

/// The session's device, seen from the servo thread: each read() ends the previous tick (the
/// allocations the servo thread made since the last read(), and the period since it), each
/// write() ends the tick's work (its compute time and the force).
class Probe final : public Device {
  public:
    explicit Probe(Device& inner) : mInner(inner) {}
    DeviceState read() noexcept override {
        const std::int64_t now = nowNs();
        const std::uint64_t allocs = palp::test::threadAllocationCount();
        if (mLastReadNs != 0) {
            period.add(std::abs(now - mLastReadNs - static_cast<std::int64_t>(kPeriod * 1e9)));
            allocations.fetch_add(allocs - mLastAllocs, std::memory_order_relaxed);
        }
        mLastReadNs = now;
        mLastAllocs = allocs;
        reads.fetch_add(1, std::memory_order_relaxed);
        return mInner.read();
    }
    void write(const Eigen::Vector3d& forceN) noexcept override {
        compute.add(nowNs() - mLastReadNs);
        const double f = forceN.norm();
        if (!std::isfinite(f)) nonFinite.fetch_add(1, std::memory_order_relaxed);
        if (f > maxForce.load(std::memory_order_relaxed))
            maxForce.store(f, std::memory_order_relaxed);
        if (f >= mInner.spec().maxForceN * (1 - 1e-9))
            clamped.fetch_add(1, std::memory_order_relaxed);
        mInner.write(forceN);
    }
    const DeviceSpec& spec() const noexcept override { return mInner.spec(); }
    DeviceHealth health() const noexcept override { return mInner.health(); }
    void reportFaults(std::uint32_t faults, double forceScale) noexcept override {
        mInner.reportFaults(faults, forceScale);
    }

    Histogram compute, period;
    std::atomic<std::uint64_t> reads{0}, allocations{0}, nonFinite{0}, clamped{0};
    std::atomic<double> maxForce{0};

  private:
    Device& mInner;
    std::int64_t mLastReadNs = 0;
    std::uint64_t mLastAllocs = 0;
};

/// The remote device of the udp scene: sends the circle's state every millisecond (absolute
/// deadlines) and reads the forces back, on its own thread.
class RemoteDevice {
  public:
    RemoteDevice(const std::string& server, const Trajectory& path)
        : mClient(server), mPath(path), mThread([this] { run(); }) {}
    ~RemoteDevice() {
        mStop.store(true);
        mThread.join();
    }
    std::atomic<std::uint64_t> sent{0}, forces{0}, flagged{0};
    std::atomic<double> maxForce{0};

  private:
    void run() {
        const std::int64_t start = nowNs();
        std::int64_t next = start;
        std::uint64_t seq = 0;
        while (!mStop.load()) {
            bridge::StateMessage m;
            m.sequence = ++seq;
            m.timeNs = static_cast<std::uint64_t>(nowNs());
            sampleTrajectory(mPath, 1e-9 * static_cast<double>(next - start), m.position,
                             m.velocity);
            if (mClient.send(m)) sent.fetch_add(1);
            bridge::ForceMessage f;
            while (mClient.receive(f, 0)) {
                forces.fetch_add(1);
                if (f.flags != 0) flagged.fetch_add(1);
                maxForce.store(std::max(maxForce.load(), f.force.norm()));
            }
            next += static_cast<std::int64_t>(kPeriod * 1e9);
            timespec ts{};
            ts.tv_sec = static_cast<time_t>(next / 1'000'000'000);
            ts.tv_nsec = static_cast<long>(next % 1'000'000'000);
            clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, &ts, nullptr);
        }
    }
    UdpBridgeClient mClient;
    Trajectory mPath;
    std::atomic<bool> mStop{false};
    std::thread mThread;
};

double residentMiB() {
    std::ifstream in("/proc/self/statm");
    long pages = 0, resident = 0;
    in >> pages >> resident;
    return static_cast<double>(resident) * static_cast<double>(sysconf(_SC_PAGESIZE)) / 1048576.0;
}

/// glibc's view of the heap (all arenas): the bytes the program holds (in use, small and mmapped
/// blocks) and the bytes the allocator holds for it (arenas and mmapped blocks). A leak raises
/// the first; fragmentation raises the second and the resident set with the first flat. Each
/// window reports the lowest of each, sampled with the resident set.
struct HeapUse {
    double inUseMiB = 0, heldMiB = 0;
};
HeapUse heapUse() {
    const struct mallinfo2 m = mallinfo2();
    return {static_cast<double>(m.uordblks + m.hblkhd) / 1048576.0,
            static_cast<double>(m.arena + m.hblkhd) / 1048576.0};
}

const DeviceSpec& touch() { return *findDeviceSpec("3D Systems Touch"); }

/// A circle of 15 mm radius at 0.5 Hz on the bone phantom's skin (y = 0, pressed along +y),
/// 3 mm deep, over the slab of bone: for ever.
CircleTrajectory circle() {
    CircleTrajectory c;
    c.centre = Eigen::Vector3d(0, 0, 0);
    c.radiusM = 0.015;
    c.frequencyHz = 0.5;
    c.depthM = 0.003;
    return c;
}

struct Options {
    std::string scene = "all";
    double seconds = 60;
    double window = 10;
    bool check = false;
    int servoCpu = -1;
    int servoPriority = 80;
    std::string femSolver = "auto";
    std::string jsonPath;
};

json runScene(const std::string& name, const Options& o, bool& ok) {
    volume::PhantomSpec spec;
    spec.params.scene = volume::PhantomScene::Bone;
    spec.voxelSize = 1e-3;
    const volume::Volume vol = volume::makePhantomVolume(spec);
    const bool deformable = name == "deformable";
    SceneOptions so;
    if (deformable) so.surfaceIso = std::numeric_limits<double>::quiet_NaN();  // the FEM skin
    std::shared_ptr<Scene> scene = Scene::fromVolume(vol, so);
    scene->commit();
    json out{{"scene", name}};
    if (deformable) {
        DeformableSetup setup;
        setup.supportFace = faceOpposite(Eigen::Vector3d(0, 1, 0));
        setup.autoSolver = o.femSolver == "auto";
        if (o.femSolver == "regions") setup.options.solverKind = DeformableSolver::asyncRegions;
        setup.setPeriod(kPeriod);
        // The regions start under the path, as `palp palpate` places them (their default is
        // the first free surface node, away from the circle).
        setup.options.regionsCentre = circle().centre;
        SolverChoice choice;
        scene->setDeformable(makeDeformableModel(vol, setup, &choice));
        out["fem_solver"] = o.femSolver == "auto" ? choice.reason : o.femSolver;
    }
    SessionParams p;
    p.coupling = sceneCouplingDefaults(volume::PhantomScene::Bone);
    p.servo.periodSeconds = kPeriod;
    p.servo.cpu = o.servoCpu;
    p.servo.priority = o.servoPriority;

    std::unique_ptr<Device> inner;
    std::unique_ptr<RemoteDevice> remote;
    UdpDevice* udp = nullptr;
    if (name == "udp") {
        UdpDeviceParams up;
        up.listen = "127.0.0.1:0";
        auto d = std::make_unique<UdpDevice>(touch(), up);
        udp = d.get();
        inner = std::move(d);
    } else {
        inner = std::make_unique<SimulatedDevice>(touch(), circle(), HandModel{}, kPeriod);
    }
    Probe probe(*inner);
    Session session(scene, probe, p);
    if (udp) remote = std::make_unique<RemoteDevice>(udp->address(), circle());
    session.start();
    out["realtime"] = {{"fifo", session.realtime().fifo},
                       {"pinned", session.realtime().pinned},
                       {"cpu", session.realtime().cpu}};

    std::printf("%-10s %7s %9s %9s %9s %9s %8s %7s %7s %9s %9s %9s %9s %7s %8s %7s %6s\n",
                name.c_str(), "t s", "RSS low", "RSS high", "heap use", "heap held", "ticks",
                "misses", "skips", "cmp p50", "cmp p99", "cmp max", "per p99", "allocs", "max F N",
                "clamped", "sheds");
    json windows = json::array();
    auto lastCompute = probe.compute.copy();
    auto lastPeriod = probe.period.copy();
    std::uint64_t lastAllocs = 0, lastTicks = 0, lastMisses = 0, lastSkipped = 0, lastClamped = 0,
                  lastSheds = 0, lastRestores = 0;
    const auto start = std::chrono::steady_clock::now();
    const int nWindows = std::max(1, static_cast<int>(std::lround(o.seconds / o.window)));
    // The resident set is sampled every 100 ms and each window keeps its trough and its peak:
    // it swings with the regions' layout builds (the deformable scene: 362-439 MiB peaks from
    // one 10 s window to the next, the memory given back after each build), so a leak shows as
    // the troughs rising: the lowest of the run's second half above the lowest of its first.
    // The first window is warm-up (the regions build and keep the layouts around the path).
    std::vector<double> troughs;
    bool allocFree = true;
    for (int w = 1; w <= nWindows; ++w) {
        const auto end = start + std::chrono::duration_cast<std::chrono::steady_clock::duration>(
                                     std::chrono::duration<double>(w * o.window));
        double peak = residentMiB(), trough = peak;
        HeapUse heap = heapUse();  // the window's lowest of each
        while (std::chrono::steady_clock::now() < end) {
            std::this_thread::sleep_until(
                std::min(end, std::chrono::steady_clock::now() + std::chrono::milliseconds(100)));
            const double r = residentMiB();
            peak = std::max(peak, r);
            trough = std::min(trough, r);
            const HeapUse h = heapUse();
            heap.inUseMiB = std::min(heap.inUseMiB, h.inUseMiB);
            heap.heldMiB = std::min(heap.heldMiB, h.heldMiB);
        }
        troughs.push_back(trough);
        const auto compute = probe.compute.copy();
        const auto period = probe.period.copy();
        const ServoStats st = session.stats();
        const std::uint64_t allocs = probe.allocations.load();
        const std::uint64_t clamped = probe.clamped.load();
        const auto dc = minus(compute, lastCompute);
        const auto dp = minus(period, lastPeriod);
        json row{{"t_s", w * o.window},
                 {"rss_trough_mib", trough},
                 {"rss_peak_mib", peak},
                 {"heap_in_use_mib", heap.inUseMiB},
                 {"heap_held_mib", heap.heldMiB},
                 {"ticks", st.ticks - lastTicks},
                 {"misses", st.misses - lastMisses},
                 {"skipped", st.skipped - lastSkipped},
                 {"compute_p50_ms", quantileMs(dc, 0.5)},
                 {"compute_p99_ms", quantileMs(dc, 0.99)},
                 {"compute_max_ms", quantileMs(dc, 1.0)},
                 {"period_error_p99_ms", quantileMs(dp, 0.99)},
                 {"servo_allocations", allocs - lastAllocs},
                 {"max_force_n", probe.maxForce.load()},
                 {"clamped_ticks", clamped - lastClamped},
                 {"sheds", st.sheds - lastSheds},
                 {"restores", st.restores - lastRestores}};
        std::printf(
            "%-10s %7.0f %9.2f %9.2f %9.2f %9.2f %8llu %7llu %7llu %9.3f %9.3f %9.3f %9.3f %7llu "
            "%8.3f %7llu %6llu\n",
            "", w * o.window, trough, peak, heap.inUseMiB, heap.heldMiB,
            static_cast<unsigned long long>(st.ticks - lastTicks),
            static_cast<unsigned long long>(st.misses - lastMisses),
            static_cast<unsigned long long>(st.skipped - lastSkipped), quantileMs(dc, 0.5),
            quantileMs(dc, 0.99), quantileMs(dc, 1.0), quantileMs(dp, 0.99),
            static_cast<unsigned long long>(allocs - lastAllocs), probe.maxForce.load(),
            static_cast<unsigned long long>(clamped - lastClamped),
            static_cast<unsigned long long>(st.sheds - lastSheds));
        std::fflush(stdout);
        if (w > 1 && allocs != lastAllocs) allocFree = false;
        windows.push_back(row);
        lastCompute = compute;
        lastPeriod = period;
        lastAllocs = allocs;
        lastTicks = st.ticks;
        lastMisses = st.misses;
        lastSkipped = st.skipped;
        lastClamped = clamped;
        lastSheds = st.sheds;
        lastRestores = st.restores;
    }
    session.stop();
    const ServoStats st = session.stats();
    const Snapshot& last = session.newest();
    out["windows"] = windows;
    out["ticks"] = st.ticks;
    out["device_reads"] = probe.reads.load();
    out["overloaded"] = st.overloaded;
    out["non_finite_forces"] = probe.nonFinite.load();
    out["max_force_n"] = probe.maxForce.load();
    out["clamped_ticks"] = probe.clamped.load();
    out["sheds"] = st.sheds;
    out["restores"] = st.restores;
    out["fault_counts"] = {{"stale", last.faultCounts.stale},
                           {"non_finite", last.faultCounts.nonFinite},
                           {"out_of_range", last.faultCounts.outOfRange},
                           {"too_fast", last.faultCounts.tooFast},
                           {"force_jump", last.faultCounts.forceJump},
                           {"overload", last.faultCounts.overload}};
    std::vector<std::string> failures;
    if (!allocFree) failures.push_back("the servo thread allocated after the first window");
    if (troughs.size() >= 3) {
        const auto mid =
            troughs.begin() + static_cast<std::ptrdiff_t>(1 + (troughs.size() - 1) / 2);
        const double before = *std::min_element(troughs.begin() + 1, mid);
        const double after = *std::min_element(mid, troughs.end());
        out["rss_trough_first_half_mib"] = before;
        out["rss_trough_second_half_mib"] = after;
        if (after > before * 1.01)
            failures.push_back("the resident set's trough grew from " + std::to_string(before) +
                               " to " + std::to_string(after) + " MiB");
    }
    if (probe.nonFinite.load() != 0) failures.push_back("non-finite forces written");
    if (probe.maxForce.load() > touch().maxForceN + 1e-9)
        failures.push_back("a force above the device's maximum");
    if (st.ticks != probe.reads.load())
        failures.push_back("the loop counted " + std::to_string(st.ticks) + " ticks, the device " +
                           std::to_string(probe.reads.load()) + " reads");
    if (st.overloaded) failures.push_back("the loop exceeded its overrun budget");
    if (remote) {
        remote.reset();  // joins: its counts are final
        const UdpDeviceCounters c = udp->counters();
        out["bridge"] = {{"states_received", c.received}, {"lost", c.lost}, {"late", c.late}};
        if (c.received == 0) failures.push_back("no state reached the session over UDP");
    }
    out["failures"] = failures;
    for (const auto& f : failures) std::printf("%-10s FAILED: %s\n", name.c_str(), f.c_str());
    if (!failures.empty()) ok = false;
    return out;
}

}  // namespace

int main(int argc, char** argv) {
    Options o;
    CLI::App app{"palp's soak: a live session for a long time, noted every window"};
    app.add_option("--scene", o.scene, "rigid, deformable, udp or all (default all)")
        ->check(CLI::IsMember({"rigid", "deformable", "udp", "all"}));
    app.add_option("--seconds", o.seconds, "Seconds per scene (default 60)")
        ->check(CLI::Range(1.0, 86400.0));
    app.add_option("--window", o.window, "Seconds per window (default 10)")
        ->check(CLI::Range(1.0, 3600.0));
    app.add_flag("--check", o.check, "Exit 1 when a scene fails its checks (see the file)");
    app.add_option("--servo-cpu", o.servoCpu, "Servo CPU (default -1: the last one)");
    app.add_option("--servo-priority", o.servoPriority, "SCHED_FIFO priority, 0 none (default 80)")
        ->check(CLI::Range(0, 99));
    app.add_option("--fem-solver", o.femSolver, "auto, explicit or regions (default auto)")
        ->check(CLI::IsMember({"auto", "explicit", "regions"}));
    app.add_option("--json", o.jsonPath, "Write the windows and the verdicts here");
    CLI11_PARSE(app, argc, argv);
    bool ok = true;
    json all = json::array();
    for (const std::string name : {"rigid", "deformable", "udp"}) {
        if (o.scene != "all" && o.scene != name) continue;
        all.push_back(runScene(name, o, ok));
    }
    if (!o.jsonPath.empty()) std::ofstream(o.jsonPath) << all.dump(2) << '\n';
    std::printf("bench_soak: %s\n", ok ? "every check held" : "a check failed");
    return o.check && !ok ? 1 : 0;
}
