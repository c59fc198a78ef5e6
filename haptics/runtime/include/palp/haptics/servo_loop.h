#pragma once
/// @file
/// The servo loop: a dedicated thread that calls a task at a fixed rate (1 kHz by default) on
/// absolute deadlines, pinned to a core, with SCHED_FIFO when the process may, and timing
/// statistics (wake-up latency, period error, compute time).

#include <array>
#include <atomic>
#include <cstdint>
#include <string>
#include <thread>

#include "palp/base/thread.h"

namespace palp::haptics {

/// Passed to the task each tick.
struct TickInfo {
    std::uint64_t index = 0;      ///< tick number from 0
    double periodSeconds = 1e-3;  ///< nominal period T, s
    double timeSeconds = 0;       ///< nominal time of this tick since start, s
    double latencySeconds = 0;    ///< how late the thread woke for this tick, s
};

/// What runs every tick. tick() must be noexcept, allocation-free, lock-free and bounded.
class ServoTask {
  public:
    virtual ~ServoTask() = default;
    virtual void tick(const TickInfo& info) noexcept = 0;
    /// Called on the servo thread between two ticks when a window of the overrun budget was
    /// over it but the budget is not yet spent (the first of ServoConfig::overrunWindows): the
    /// task sheds the work it can shed and keeps rendering (Session: VC coupling instead of
    /// AVC/AVCEC's ray bundles, the deformable tissue frozen). Returns false when it has nothing
    /// to shed. If the next windows are still over the budget, overloaded() follows as before.
    /// Default: false.
    virtual bool shed() noexcept { return false; }
    /// Called on the servo thread when a loop that shed has kept ServoConfig::shedRestoreSeconds
    /// of windows well inside the budget: the task takes back what shed() dropped. Default:
    /// nothing.
    virtual void restore() noexcept {}
    /// Called once per run, on the servo thread between two ticks, when the loop has exceeded
    /// its overrun budget (ServoConfig::overrunWindowSeconds): the task should stop rendering
    /// force and shed the work it can (Session does both). Default: nothing.
    virtual void overloaded() noexcept {}
};

struct ServoConfig {
    double periodSeconds = 1e-3;   ///< T, s (1e-5 .. 1)
    int cpu = -1;                  ///< core to pin to; -1: the last core the process may use
    int priority = 80;             ///< SCHED_FIFO priority (1..99); 0: do not ask for SCHED_FIFO
    bool requireRealtime = false;  ///< start() throws when pinning or SCHED_FIFO fails
    double spinSeconds = 0;        ///< busy-wait this long before each deadline (0: sleep only)
    bool lockMemory = false;       ///< mlockall(MCL_CURRENT | MCL_FUTURE) at start (reported)
    /// While the loop runs, keep the process's other threads off its CPU (palp::CpuReservation:
    /// their affinity masks lose it, and get it back at stop()); only when pinned and the
    /// process may use another CPU. Without it a solver's or TBB's threads share the servo's
    /// CPU: preempted, but their memory traffic leaves the servo's caches cold (the head CT at
    /// 2.5 mm cells: 46 % of the servo CPU's time went to the regions' other threads).
    bool reserveCpu = true;
    /// The overrun budget of a loop that got SCHED_FIFO (a SCHED_OTHER loop cannot starve its
    /// CPU: the scheduler shares it; its misses are not counted): when, in overrunWindows
    /// consecutive windows of this long, more than
    /// overrunFraction of each window's deadlines were missed (ticks that ended late plus the
    /// deadlines they skipped), the loop is overloaded: it calls ServoTask::overloaded() once,
    /// then drops SCHED_FIFO for SCHED_OTHER, so a loop that cannot keep up never holds its CPU
    /// at real-time priority for longer than overrunWindows windows plus one tick (0.8 s plus a
    /// tick by default; two windows, so that a slow start, a deformable body's first ticks, is
    /// not taken for an overload); ServoStats::overloaded says when. s, 0 .. 60; 0: no budget.
    /// Before it gives up, the loop sheds: after the first window over the budget (of
    /// overrunWindows >= 2) it calls ServoTask::shed() once; the task keeps rendering with less
    /// work. A window under the budget then clears the count as before; a window over it still
    /// counts, so the bound above holds whether or not shedding helped.
    double overrunWindowSeconds = 0.4;
    int overrunWindows = 2;        ///< consecutive windows over the budget (1 .. 100)
    double overrunFraction = 0.5;  ///< (0, 1]
    /// A loop that shed gives the task its work back (ServoTask::restore()) once every window
    /// of this long has missed at most a quarter of overrunFraction of its deadlines; it may
    /// shed again later. s, 0 .. 3600; 0: never restore (shed until the next start()).
    double shedRestoreSeconds = 10;
};

/// @throw palp::ValueError naming the field.
void validateServoConfig(const ServoConfig& config);

/// What the loop obtained from the OS; never silently ignored: check it, print it.
struct RealtimeStatus {
    bool pinned = false;
    int cpu = -1;
    bool fifo = false;
    int priority = 0;
    bool memoryLocked = false;
    std::size_t threadsMovedOff = 0;  ///< other threads reserveCpu moved off the servo's CPU
    /// Every outcome, "; "-separated, e.g. "pinned to CPU 1; SCHED_FIFO 80 refused: Operation
    /// not permitted (EPERM); memory not locked (not asked)". Never empty after start().
    std::string message;
    bool failed = false;  ///< something asked for (pinning, SCHED_FIFO, mlockall) was refused
};

/// A fixed-bin latency histogram (1 us bins to 20 ms, plus overflow), filled on the servo
/// thread without allocation and read from any thread (relaxed atomics: a reader may see a
/// tick half-counted across histograms, never a torn count).
class LatencyHistogram {
  public:
    static constexpr int kBins = 20000;  ///< bin i: [i, i + 1) microseconds
    void add(double seconds) noexcept;
    void reset() noexcept;
    std::uint64_t count() const noexcept;
    /// Quantile q in [0, 1], seconds (upper edge of the bin; max() for the overflow).
    double quantile(double q) const noexcept;
    double max() const noexcept;   ///< exact maximum, s
    double mean() const noexcept;  ///< s

  private:
    std::array<std::atomic<std::uint32_t>, kBins> mBins{};
    std::atomic<std::uint64_t> mOverflow{0}, mCount{0};
    std::atomic<double> mMax{0}, mSum{0};
};

/// Summary figures of one histogram, seconds.
struct LatencySummary {
    double p50 = 0, p99 = 0, p999 = 0, max = 0, mean = 0;
    std::uint64_t count = 0;
};

struct ServoStats {
    LatencySummary wakeLatency;  ///< actual wake-up minus deadline
    LatencySummary periodError;  ///< |actual period - T|
    LatencySummary compute;      ///< time in ServoTask::tick()
    std::uint64_t ticks = 0;
    std::uint64_t misses = 0;   ///< ticks whose tick() ended after the next deadline
    std::uint64_t skipped = 0;  ///< deadlines dropped to catch up after an overrun
    /// The overrun budget was exceeded (ServoConfig::overrunWindowSeconds): the loop dropped
    /// SCHED_FIFO (fifoDropped: it had it) and told the task, which stopped rendering force.
    bool overloaded = false;
    bool fifoDropped = false;
    double overloadedAtSeconds = 0;  ///< when, since the first deadline, s
    double missedFraction = 0;       ///< of the last window that exceeded the budget
    /// The task has shed work (ServoTask::shed() returned true) and not yet been restored.
    bool shedding = false;
    std::uint64_t sheds = 0;     ///< shed() calls that shed something, this run
    std::uint64_t restores = 0;  ///< restore() calls, this run
    /// Windows, while shed, that missed more than a quarter of the budget: each one restarts
    /// the calm time restore() waits for (a busy host delays the restore by these).
    std::uint64_t unsettledWindows = 0;
    double shedAtSeconds = 0;  ///< the last shed, since the first deadline, s
};

/// Runs a ServoTask on its own thread.
///
/// @par Threading  start(), stop() and the destructor from one controlling thread; stats()
///      and running() from any thread.
/// @par Real-time  The loop itself never allocates, locks, logs or throws after start.
class ServoLoop {
  public:
    explicit ServoLoop(const ServoConfig& config = {});
    ~ServoLoop();  ///< stops the loop
    ServoLoop(const ServoLoop&) = delete;
    ServoLoop& operator=(const ServoLoop&) = delete;

    /// Starts the thread (named "palp-servo"; pinning, SCHED_FIFO and naming through
    /// palp/base/thread.h); returns after it has set its affinity and policy (see realtime()).
    /// @throw palp::Error when already running, when the thread cannot start, or (with
    ///        requireRealtime) when pinning or SCHED_FIFO failed.
    void start(ServoTask& task);
    /// Asks the loop to stop after the current tick and joins it. Idempotent.
    void stop() noexcept;
    bool running() const noexcept;

    const RealtimeStatus& realtime() const noexcept { return mStatus; }
    ServoStats stats() const noexcept;
    void resetStats() noexcept;
    const ServoConfig& config() const noexcept { return mConfig; }

  private:
    void run(ServoTask* task) noexcept;
    void setUpThread() noexcept;  // affinity, policy, mlockall: fills mStatus
    // The overrun budget is exceeded: SCHED_OTHER, report, tell the task (servo thread).
    void overload(std::int64_t atNs, double missedFraction, ServoTask& task) noexcept;
    ServoConfig mConfig;
    RealtimeStatus mStatus;
    std::thread mThread;
    std::atomic<bool> mStop{false}, mRunning{false};
    std::atomic<bool> mReady{false};  // set (release) by the thread once mStatus is final
    LatencyHistogram mWake, mPeriodError, mCompute;
    std::atomic<std::uint64_t> mTicks{0}, mMisses{0}, mSkipped{0};
    // The overrun budget's verdict (servo thread writes, any thread reads).
    std::atomic<bool> mOverloaded{false}, mFifoDropped{false};
    std::atomic<double> mOverloadedAt{0}, mMissedFraction{0};
    std::atomic<bool> mShedding{false};
    std::atomic<std::uint64_t> mSheds{0}, mRestores{0}, mUnsettled{0};
    std::atomic<double> mShedAt{0};
    CpuReservation mReservation;  // set up on the servo thread, released by stop()
};

}  // namespace palp::haptics
