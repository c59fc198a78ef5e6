#include "palp/haptics/servo_loop.h"

#include <pthread.h>
#include <sched.h>
#include <sys/mman.h>
#include <sys/prctl.h>
#include <time.h>

#include <algorithm>
#include <cerrno>
#include <cmath>
#include <cstring>
#include <new>
#include <string>
#include <system_error>
#include <vector>

#include "palp/base/bounds.h"
#include "palp/base/error.h"
#include "palp/base/thread.h"
#include "palp/base/validate.h"

namespace palp::haptics {

namespace {

constexpr std::int64_t kNsPerSecond = 1'000'000'000;

std::int64_t nowNs() noexcept {
    timespec ts{};
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return static_cast<std::int64_t>(ts.tv_sec) * kNsPerSecond + ts.tv_nsec;
}

/// Sleeps until the absolute CLOCK_MONOTONIC time t (ns); restarts after signals.
void sleepUntilNs(std::int64_t t) noexcept {
    timespec ts{};
    ts.tv_sec = static_cast<time_t>(t / kNsPerSecond);
    ts.tv_nsec = static_cast<long>(t % kNsPerSecond);
    while (clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, &ts, nullptr) == EINTR) {
    }
}

void cpuRelax() noexcept {
#if defined(__x86_64__) || defined(__i386__)
    __builtin_ia32_pause();
#endif
}

/// "Operation not permitted (EPERM)" for an errno value.
std::string errorWithName(int err) {
    std::string s = errorText(err);
    if (const char* name = strerrorname_np(err)) s += std::string(" (") + name + ")";
    return s;
}

std::string microseconds(double seconds) { return formatValue(seconds * 1e6) + " us"; }

}  // namespace

void validateServoConfig(const ServoConfig& c) {
    requireWithin("servo config periodSeconds", c.periodSeconds, bounds::kPeriod);
    if (c.priority < 0 || c.priority > 99)
        throw ValueError(
            "servo config: priority must be 0 (no SCHED_FIFO) or a SCHED_FIFO priority 1..99, "
            "found " +
            std::to_string(c.priority));
    if (c.cpu < -1 || c.cpu > 65535)
        throw ValueError("servo config: cpu must be -1 (last allowed CPU) or 0..65535, found " +
                         std::to_string(c.cpu));
    requireInRange("servo config overrunWindowSeconds (0: no budget)", c.overrunWindowSeconds, 0.0,
                   60.0, "s");
    if (c.overrunWindows < 1 || c.overrunWindows > 100)
        throw ValueError("servo config: overrunWindows must be 1..100, found " +
                         std::to_string(c.overrunWindows));
    if (!(c.overrunFraction > 0 && c.overrunFraction <= 1))
        throwExpected("servo config overrunFraction", "a fraction in (0, 1]",
                      formatValue(c.overrunFraction));
    requireInRange("servo config shedRestoreSeconds (0: never)", c.shedRestoreSeconds, 0.0, 3600.0,
                   "s");
    if (!std::isfinite(c.spinSeconds) || c.spinSeconds < 0 || c.spinSeconds >= c.periodSeconds)
        throw ValueError("servo config: spinSeconds must be in [0, periodSeconds = " +
                         microseconds(c.periodSeconds) + "), found " + formatValue(c.spinSeconds) +
                         " s");
}

// ---------------------------------------------------------------------------------------------
// LatencyHistogram. One writer (the servo thread), any number of readers; reset() may come from
// another thread, so the running sums use read-modify-write atomics rather than load + store.

void LatencyHistogram::add(double seconds) noexcept {
    if (!(seconds > 0)) seconds = 0;  // also NaN
    const double us = seconds * 1e6;
    if (us < static_cast<double>(kBins))
        mBins[static_cast<std::size_t>(us)].fetch_add(1, std::memory_order_relaxed);
    else
        mOverflow.fetch_add(1, std::memory_order_relaxed);
    mSum.fetch_add(seconds, std::memory_order_relaxed);
    double m = mMax.load(std::memory_order_relaxed);
    while (seconds > m && !mMax.compare_exchange_weak(m, seconds, std::memory_order_relaxed)) {
    }
    mCount.fetch_add(1, std::memory_order_relaxed);
}

void LatencyHistogram::reset() noexcept {
    for (auto& b : mBins) b.store(0, std::memory_order_relaxed);
    mOverflow.store(0, std::memory_order_relaxed);
    mCount.store(0, std::memory_order_relaxed);
    mMax.store(0, std::memory_order_relaxed);
    mSum.store(0, std::memory_order_relaxed);
}

std::uint64_t LatencyHistogram::count() const noexcept {
    return mCount.load(std::memory_order_relaxed);
}

double LatencyHistogram::max() const noexcept { return mMax.load(std::memory_order_relaxed); }

double LatencyHistogram::mean() const noexcept {
    const std::uint64_t n = count();
    return n ? mSum.load(std::memory_order_relaxed) / static_cast<double>(n) : 0.0;
}

double LatencyHistogram::quantile(double q) const noexcept {
    // Count from the bins themselves, so that a concurrent add() cannot make the target rank
    // unreachable.
    std::uint64_t n = mOverflow.load(std::memory_order_relaxed);
    for (const auto& b : mBins) n += b.load(std::memory_order_relaxed);
    if (n == 0) return 0.0;
    q = std::clamp(std::isnan(q) ? 1.0 : q, 0.0, 1.0);
    // Rank r (1-based) is the smallest with r >= q n; the small slack keeps q n = 999.0000001
    // from meaning rank 1000.
    const double target = std::ceil(q * static_cast<double>(n) - 1e-9);
    const std::uint64_t rank =
        std::clamp<std::uint64_t>(static_cast<std::uint64_t>(std::max(target, 1.0)), 1, n);
    const double top = max();
    std::uint64_t cumulative = 0;
    for (int i = 0; i < kBins; ++i) {
        cumulative += mBins[static_cast<std::size_t>(i)].load(std::memory_order_relaxed);
        // The upper edge of the bin, but never above the exact maximum (which lies in the
        // highest non-empty bin), so p50 <= p99 <= p99.9 <= max always holds.
        if (cumulative >= rank) return std::min(static_cast<double>(i + 1) * 1e-6, top);
    }
    return top;  // in the overflow
}

namespace {
LatencySummary summarise(const LatencyHistogram& h) noexcept {
    LatencySummary s;
    s.count = h.count();
    s.p50 = h.quantile(0.5);
    s.p99 = h.quantile(0.99);
    s.p999 = h.quantile(0.999);
    s.max = h.max();
    s.mean = h.mean();
    return s;
}
}  // namespace

// ---------------------------------------------------------------------------------------------
// ServoLoop

ServoLoop::ServoLoop(const ServoConfig& config) : mConfig(config) { validateServoConfig(config); }

ServoLoop::~ServoLoop() { stop(); }

bool ServoLoop::running() const noexcept { return mRunning.load(std::memory_order_acquire); }

void ServoLoop::start(ServoTask& task) {
    if (mThread.joinable())
        throw Error("servo loop: start() called while the loop is running; call stop() first");
    mStop.store(false, std::memory_order_relaxed);
    mReady.store(false, std::memory_order_relaxed);
    mStatus = RealtimeStatus{};
    try {
        mThread = std::thread([this, t = &task] { run(t); });
    } catch (const std::system_error& e) {
        throw Error(std::string("servo loop: cannot start the servo thread: ") + e.what());
    }
    // Set-up hand-off: the thread fills mStatus, then publishes mReady (release).
    mReady.wait(false, std::memory_order_acquire);
    if (mConfig.requireRealtime && mStatus.failed) {
        mThread.join();  // the thread returns without ticking when it failed and must not run
        mReservation.release();
        throw Error("servo loop: real-time set-up required but refused: " + mStatus.message);
    }
}

void ServoLoop::stop() noexcept {
    mStop.store(true, std::memory_order_relaxed);
    if (mThread.joinable()) mThread.join();
    mReservation.release();  // the other threads may use the servo's CPU again
}

ServoStats ServoLoop::stats() const noexcept {
    ServoStats s;
    s.ticks = mTicks.load(std::memory_order_relaxed);
    s.misses = mMisses.load(std::memory_order_relaxed);
    s.skipped = mSkipped.load(std::memory_order_relaxed);
    s.wakeLatency = summarise(mWake);
    s.periodError = summarise(mPeriodError);
    s.compute = summarise(mCompute);
    s.overloaded = mOverloaded.load(std::memory_order_acquire);
    s.fifoDropped = mFifoDropped.load(std::memory_order_relaxed);
    s.overloadedAtSeconds = mOverloadedAt.load(std::memory_order_relaxed);
    s.missedFraction = mMissedFraction.load(std::memory_order_relaxed);
    s.shedding = mShedding.load(std::memory_order_relaxed);
    s.sheds = mSheds.load(std::memory_order_relaxed);
    s.restores = mRestores.load(std::memory_order_relaxed);
    s.unsettledWindows = mUnsettled.load(std::memory_order_relaxed);
    s.shedAtSeconds = mShedAt.load(std::memory_order_relaxed);
    return s;
}

void ServoLoop::resetStats() noexcept {
    mWake.reset();
    mPeriodError.reset();
    mCompute.reset();
    mTicks.store(0, std::memory_order_relaxed);
    mMisses.store(0, std::memory_order_relaxed);
    mSkipped.store(0, std::memory_order_relaxed);
}

void ServoLoop::overload(std::int64_t atNs, double missedFraction, ServoTask& task) noexcept {
    // The task first (it stops rendering force while it still runs at its priority), then
    // SCHED_OTHER for this thread (one system call; nothing to allocate): a loop that cannot keep
    // up must not starve its CPU.
    task.overloaded();
    bool dropped = false;
    if (mStatus.fifo) {
        sched_param param{};
        param.sched_priority = 0;
        dropped = pthread_setschedparam(pthread_self(), SCHED_OTHER, &param) == 0;
    }
    mFifoDropped.store(dropped, std::memory_order_relaxed);
    mOverloadedAt.store(static_cast<double>(atNs) * 1e-9, std::memory_order_relaxed);
    mMissedFraction.store(missedFraction, std::memory_order_relaxed);
    mOverloaded.store(true, std::memory_order_release);
}

void ServoLoop::setUpThread() noexcept {
    // Runs on the servo thread before the loop; may allocate (set-up, not real-time).
    RealtimeStatus& st = mStatus;
    std::string msg;
    auto append = [&msg](const std::string& part) {
        if (!msg.empty()) msg += "; ";
        msg += part;
    };

    // Affinity. cpu -1: the last CPU of this thread's mask (inherited from the process).
    int cpu = mConfig.cpu;
    const std::vector<int> allowed = allowedCpus();
    const int maskErrno = errno;  // allowedCpus() leaves sched_getaffinity's errno
    const std::string allowedText = allowed.empty() ? "unknown" : cpuListText(allowed);
    if (cpu < 0 && !allowed.empty()) cpu = allowed.back();
    if (cpu < 0) {
        st.failed = true;
        append("not pinned: cannot read the process's CPU affinity mask: " +
               errorWithName(maskErrno));
    } else if (const int rc = pinCurrentThread(cpu); rc == 0) {
        st.pinned = true;
        st.cpu = cpu;
        append("pinned to CPU " + std::to_string(cpu));
    } else {
        st.failed = true;
        append("pinning to CPU " + std::to_string(cpu) + " refused: " + errorWithName(rc) +
               " (the process may use CPUs " + allowedText + ")");
    }
    if (st.pinned && mConfig.reserveCpu) {
        try {
            mReservation = CpuReservation::reserve(cpu);
            st.threadsMovedOff = mReservation.threadsMoved();
            append(std::to_string(st.threadsMovedOff) + " other threads moved off it");
        } catch (const std::bad_alloc&) {
            append("other threads not moved off it (out of memory)");
        }
    }
    nameCurrentThread("palp-servo");  // best effort: only top, perf and gdb show it

    // Timer slack: SCHED_OTHER threads default to 50 us, which would show as wake latency when
    // SCHED_FIFO is refused (SCHED_FIFO threads get none). Best effort; nothing to report.
    prctl(PR_SET_TIMERSLACK, 1UL, 0UL, 0UL, 0UL);

    // Scheduling policy.
    if (mConfig.priority > 0) {
        const int rc = setCurrentThreadFifo(mConfig.priority);
        if (rc == 0) {
            st.fifo = true;
            st.priority = mConfig.priority;
            append("SCHED_FIFO " + std::to_string(mConfig.priority));
        } else {
            st.failed = true;
            append("SCHED_FIFO " + std::to_string(mConfig.priority) +
                   " refused: " + errorWithName(rc));
        }
    } else {
        append("SCHED_OTHER (priority 0: SCHED_FIFO not asked)");
    }

    // Memory.
    if (mConfig.lockMemory) {
        if (mlockall(MCL_CURRENT | MCL_FUTURE) == 0) {
            st.memoryLocked = true;
            append("memory locked");
            // Fault in some stack now rather than on a first deep call inside a tick.
            volatile char stack[64 * 1024];
            for (std::size_t i = 0; i < sizeof(stack); i += 4096) stack[i] = 0;
        } else {
            st.failed = true;
            append("mlockall refused: " + errorWithName(errno));
        }
    } else {
        append("memory not locked (not asked)");
    }
    st.message = std::move(msg);
}

void ServoLoop::run(ServoTask* task) noexcept {
    mOverloaded.store(false, std::memory_order_relaxed);
    mFifoDropped.store(false, std::memory_order_relaxed);
    mShedding.store(false, std::memory_order_relaxed);
    mSheds.store(0, std::memory_order_relaxed);
    mRestores.store(0, std::memory_order_relaxed);
    mUnsettled.store(0, std::memory_order_relaxed);
    mShedAt.store(0, std::memory_order_relaxed);
    setUpThread();
    const bool abort = mConfig.requireRealtime && mStatus.failed;
    if (!abort) mRunning.store(true, std::memory_order_release);
    mReady.store(true, std::memory_order_release);
    mReady.notify_one();
    if (abort) return;

    // From here on: no allocation, no lock, no I/O.
    const std::int64_t periodNs = std::llround(mConfig.periodSeconds * 1e9);
    const std::int64_t spinNs = std::llround(mConfig.spinSeconds * 1e9);
    const std::int64_t startNs = nowNs() + periodNs;  // nominal time 0 = first deadline
    std::int64_t deadline = startNs;
    std::int64_t previousWake = 0;
    std::uint64_t index = 0;
    // The overrun budget's window: its start, and the deadlines missed in it.
    const std::int64_t windowNs = std::llround(mConfig.overrunWindowSeconds * 1e9);
    std::int64_t windowStart = startNs;
    std::uint64_t windowMissed = 0;
    int windowsOver = 0;  // consecutive windows over the budget
    bool overloadedRun = false;
    // Shedding: whether the task has shed, and how long it has been calm since (windows that
    // missed at most a quarter of the budget's fraction).
    const std::int64_t restoreNs = std::llround(mConfig.shedRestoreSeconds * 1e9);
    bool shedding = false;
    std::int64_t calmNs = 0;
    while (!mStop.load(std::memory_order_relaxed)) {
        if (spinNs > 0) {
            sleepUntilNs(deadline - spinNs);
            while (nowNs() < deadline) cpuRelax();
        } else {
            sleepUntilNs(deadline);
        }
        const std::int64_t wake = nowNs();
        const std::int64_t latency = std::max<std::int64_t>(0, wake - deadline);
        mWake.add(static_cast<double>(latency) * 1e-9);
        if (index > 0)
            mPeriodError.add(static_cast<double>(std::llabs(wake - previousWake - periodNs)) *
                             1e-9);

        TickInfo info;
        info.index = index;
        info.periodSeconds = mConfig.periodSeconds;
        info.timeSeconds = static_cast<double>(deadline - startNs) * 1e-9;
        info.latencySeconds = static_cast<double>(latency) * 1e-9;
        task->tick(info);

        const std::int64_t end = nowNs();
        mCompute.add(static_cast<double>(end - wake) * 1e-9);
        mTicks.fetch_add(1, std::memory_order_relaxed);

        deadline += periodNs;
        if (end > deadline) {
            // Overrun: drop every deadline that has already passed instead of running the
            // late ticks back to back.
            mMisses.fetch_add(1, std::memory_order_relaxed);
            const std::int64_t passed = (end - deadline) / periodNs + 1;
            mSkipped.fetch_add(static_cast<std::uint64_t>(passed), std::memory_order_relaxed);
            deadline += passed * periodNs;
            windowMissed += static_cast<std::uint64_t>(passed);  // the deadlines skipped
        }
        // Only a SCHED_FIFO loop can starve its CPU; a SCHED_OTHER one shares it with the rest of
        // the machine, whose load its misses mostly measure.
        if (windowNs > 0 && mStatus.fifo && !overloadedRun && end - windowStart >= windowNs) {
            // The deadlines the window held, and the share of them skipped.
            const double periods =
                static_cast<double>(end - windowStart) / static_cast<double>(periodNs);
            const double missed = static_cast<double>(windowMissed) / std::max(periods, 1.0);
            windowsOver = missed > mConfig.overrunFraction ? windowsOver + 1 : 0;
            if (windowsOver >= mConfig.overrunWindows) {
                overloadedRun = true;
                overload(end - startNs, missed, *task);
            } else if (windowsOver > 0 && !shedding) {
                // The budget is not spent yet: shed what can be shed, keep rendering.
                if (task->shed()) {
                    shedding = true;
                    calmNs = 0;
                    mShedAt.store(static_cast<double>(end - startNs) * 1e-9,
                                  std::memory_order_relaxed);
                    mSheds.fetch_add(1, std::memory_order_relaxed);
                    mShedding.store(true, std::memory_order_relaxed);
                }
            } else if (shedding && restoreNs > 0) {
                if (missed <= 0.25 * mConfig.overrunFraction) {
                    calmNs += end - windowStart;
                } else {
                    calmNs = 0;
                    mUnsettled.fetch_add(1, std::memory_order_relaxed);
                }
                if (calmNs >= restoreNs) {
                    task->restore();
                    shedding = false;
                    mRestores.fetch_add(1, std::memory_order_relaxed);
                    mShedding.store(false, std::memory_order_relaxed);
                }
            }
            windowStart = end;
            windowMissed = 0;
        }
        previousWake = wake;
        ++index;
    }
    mRunning.store(false, std::memory_order_release);
}

}  // namespace palp::haptics
