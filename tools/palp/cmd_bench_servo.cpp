// palp bench servo: the servo loop's wake-up latency, period error and misses on this machine,
// optionally with the other cores busy (for the comparison with cyclictest, see
// bench/haptics/servo_vs_cyclictest.sh).
#include <atomic>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <memory>
#include <nlohmann/json.hpp>
#include <string>
#include <thread>
#include <vector>

#include "commands.h"
#include "option_checks.h"
#include "palp/base/thread.h"
#include "palp/haptics/servo_loop.h"

namespace palp::tool {

using nlohmann::json;

namespace {

/// A fixed amount of dependent floating-point arithmetic per tick (the stand-in for a haptic
/// frame), calibrated once before the loop starts.
class WorkTask final : public haptics::ServoTask {
  public:
    explicit WorkTask(double workSeconds) {
        if (workSeconds <= 0) return;
        // Calibrate: time a block of iterations on this thread (not pinned; close enough).
        const std::uint64_t probe = 2'000'000;
        const auto t0 = std::chrono::steady_clock::now();
        spin(probe);
        const double s =
            std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
        mIterations = static_cast<std::uint64_t>(workSeconds * static_cast<double>(probe) /
                                                 std::max(s, 1e-9));
    }
    void tick(const haptics::TickInfo&) noexcept override { spin(mIterations); }
    double sink() const noexcept { return mSink; }

  private:
    void spin(std::uint64_t n) noexcept {
        double x = mSink;
        for (std::uint64_t i = 0; i < n; ++i) x = x * 0.999999 + 1e-7;
        mSink = x;
    }
    std::uint64_t mIterations = 0;
    double mSink = 1.0;
};

/// Busy threads pinned to every CPU of the process's mask except `servoCpu`.
class CpuLoad {
  public:
    explicit CpuLoad(int servoCpu) {
        for (const int c : allowedCpus()) {
            if (c == servoCpu) continue;
            mCpus.push_back(c);
            mThreads.emplace_back([this, c] {
                pinCurrentThread(c);  // a refused pin only spreads the load less evenly
                volatile double x = 1.0;
                while (!mStop.load(std::memory_order_relaxed)) x = x * 1.0000001 + 1e-9;
            });
        }
    }
    ~CpuLoad() {
        mStop.store(true, std::memory_order_relaxed);
        for (auto& t : mThreads) t.join();
    }
    const std::vector<int>& cpus() const noexcept { return mCpus; }

  private:
    std::atomic<bool> mStop{false};
    std::vector<int> mCpus;
    std::vector<std::thread> mThreads;
};

/// Microseconds rounded to 1 ns, so that bin edges print as whole numbers.
double us(double seconds) { return std::round(seconds * 1e9) * 1e-3; }

json summaryJson(const haptics::LatencySummary& s) {
    return {{"p50_us", us(s.p50)}, {"p99_us", us(s.p99)},   {"p999_us", us(s.p999)},
            {"max_us", us(s.max)}, {"mean_us", us(s.mean)}, {"count", s.count}};
}

void printSummary(const char* name, const haptics::LatencySummary& s) {
    std::printf("%-13s p50 %7.1f us  p99 %7.1f us  p99.9 %7.1f us  max %8.1f us  mean %7.2f us\n",
                name, s.p50 * 1e6, s.p99 * 1e6, s.p999 * 1e6, s.max * 1e6, s.mean * 1e6);
}

}  // namespace

Command addBenchServo(CLI::App& bench) {
    struct Args {
        double seconds = 10;
        double periodUs = 1000;
        int cpu = -1;
        int priority = 80;
        double spinUs = 0;
        double workUs = 0;
        double warmUpSeconds = 0.2;
        bool load = false;
        bool lockMemory = false;
        bool requireRealtime = false;
        bool json = false;
    };
    auto args = std::make_shared<Args>();
    CLI::App* app = bench.add_subcommand(
        "servo",
        "Servo loop timing on this machine: wake-up latency, period error, misses (compare "
        "with cyclictest: bench/haptics/servo_vs_cyclictest.sh)");
    app->add_option("--seconds", args->seconds, "Measured duration, s (default 10)")
        ->check(within(bounds::kPositiveDuration));
    app->add_option("--period-us", args->periodUs, "Servo period, us (default 1000)")
        ->check(within(bounds::kPeriod, {1e6, "us"}));
    app->add_option("--cpu", args->cpu, "CPU to pin the servo thread to (default: the last one)")
        ->check(integerIn(-1, 65535));
    app->add_option("--priority", args->priority,
                    "SCHED_FIFO priority 1..99, 0 for none (default 80)")
        ->check(integerIn(0, 99));
    app->add_option("--spin-us", args->spinUs,
                    "Busy-wait this long before each deadline, us (default 0: sleep only)")
        ->check(within(bounds::kPeriodPart, {1e6, "us"}));
    app->add_option("--work-us", args->workUs,
                    "Fixed arithmetic per tick, about this many us (default 0: empty task)")
        ->check(within(bounds::kPeriodPart, {1e6, "us"}));
    app->add_option("--warm-up", args->warmUpSeconds,
                    "Seconds run before the statistics are reset (default 0.2)")
        ->check(within(bounds::kDuration));
    app->add_flag("--load", args->load,
                  "Keep every other CPU of the process busy for the duration");
    app->add_flag("--mlock", args->lockMemory, "mlockall(MCL_CURRENT | MCL_FUTURE) first");
    app->add_flag("--require-realtime", args->requireRealtime,
                  "Fail when pinning, SCHED_FIFO or --mlock is refused");
    app->add_flag("--json", args->json, "Print the figures as JSON");

    return {app, [args]() -> int {
                haptics::ServoConfig config;
                config.periodSeconds = args->periodUs * 1e-6;
                config.cpu = args->cpu;
                config.priority = args->priority;
                config.spinSeconds = args->spinUs * 1e-6;
                config.lockMemory = args->lockMemory;
                config.requireRealtime = args->requireRealtime;
                haptics::validateServoConfig(config);

                WorkTask task(args->workUs * 1e-6);
                haptics::ServoLoop loop(config);
                if (!globals().quiet && !args->json)
                    std::fprintf(stderr, "palp: running the servo loop for %g s...\n",
                                 args->seconds + args->warmUpSeconds);
                loop.start(task);
                std::vector<int> loadCpus;
                {
                    std::unique_ptr<CpuLoad> load;
                    if (args->load) {
                        load = std::make_unique<CpuLoad>(loop.realtime().cpu);
                        loadCpus = load->cpus();
                    }
                    std::this_thread::sleep_for(std::chrono::duration<double>(args->warmUpSeconds));
                    loop.resetStats();
                    std::this_thread::sleep_for(std::chrono::duration<double>(args->seconds));
                    loop.stop();
                }
                const haptics::ServoStats s = loop.stats();
                const haptics::RealtimeStatus& rt = loop.realtime();
                if (args->json) {
                    json j;
                    j["realtime"] = {{"pinned", rt.pinned},
                                     {"cpu", rt.cpu},
                                     {"fifo", rt.fifo},
                                     {"priority", rt.priority},
                                     {"memory_locked", rt.memoryLocked},
                                     {"message", rt.message}};
                    j["period_us"] = args->periodUs;
                    j["seconds"] = args->seconds;
                    j["spin_us"] = args->spinUs;
                    j["work_us"] = args->workUs;
                    j["load_cpus"] = loadCpus;
                    j["wake_latency"] = summaryJson(s.wakeLatency);
                    j["period_error"] = summaryJson(s.periodError);
                    j["compute"] = summaryJson(s.compute);
                    j["ticks"] = s.ticks;
                    j["misses"] = s.misses;
                    j["skipped"] = s.skipped;
                    std::printf("%s\n", j.dump(2).c_str());
                } else {
                    std::printf("realtime: %s\n", rt.message.c_str());
                    std::printf(
                        "period %g us, %g s measured, spin %g us, work %g us, load on CPUs %s\n",
                        args->periodUs, args->seconds, args->spinUs, args->workUs,
                        cpuListText(loadCpus).c_str());
                    printSummary("wake latency", s.wakeLatency);
                    printSummary("period error", s.periodError);
                    printSummary("compute", s.compute);
                    std::printf("ticks %llu, misses %llu, skipped deadlines %llu\n",
                                static_cast<unsigned long long>(s.ticks),
                                static_cast<unsigned long long>(s.misses),
                                static_cast<unsigned long long>(s.skipped));
                }
                if (task.sink() == 42.0) std::fprintf(stderr, " ");  // keep the work alive
                return 0;
            }};
}

}  // namespace palp::tool
