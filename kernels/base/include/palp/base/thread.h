#pragma once
/// @file
/// Thread set-up shared by the servo loop, the secondary FEM solver, the benchmarks and the
/// tools: which CPUs the process may use, pinning, SCHED_FIFO, names. Linux only.
///
/// @par Threading
/// Each function acts on the calling thread (or reads the process's mask) and may be called
/// from any thread. None is real-time: call them once when a thread starts, not per tick.
/// Failures are returned as error numbers, never thrown, so a caller decides whether a refused
/// request is fatal and reports it in its own words (errorText()).

#include <sched.h>
#include <sys/types.h>

#include <cstddef>
#include <string>
#include <vector>

namespace palp {

/// The CPUs the calling thread may run on (its affinity mask, inherited from the process),
/// ascending; empty when the mask cannot be read.
std::vector<int> allowedCpus();

/// @p cpus as a compact list, e.g. `0-3,6`; `none` when empty.
std::string cpuListText(const std::vector<int>& cpus);

/// Pins the calling thread to CPU @p cpu (any number the kernel supports).
/// @return 0, or the error number (EINVAL for a negative @p cpu or one outside the mask).
int pinCurrentThread(int cpu) noexcept;

/// Restricts the calling thread to @p cpus (e.g. to undo a pin). @return 0 or an error number.
int setCurrentThreadCpus(const std::vector<int>& cpus) noexcept;

/// Runs the calling thread under SCHED_FIFO at @p priority (1-99). Needs CAP_SYS_NICE or an
/// RLIMIT_RTPRIO that allows it. @return 0 or the error number (EPERM when refused).
int setCurrentThreadFifo(int priority) noexcept;

/// Names the calling thread for top, perf and gdb (cut to the kernel's 15 characters).
/// @return 0 or an error number.
int nameCurrentThread(const char* name) noexcept;

/// The message of error number @p err (strerror_r), e.g. `Operation not permitted`.
std::string errorText(int err);

/// A CPU kept for the calling thread: every other thread of the process whose affinity mask
/// holds that CPU and at least one more loses it (threads they start later inherit the
/// narrower mask), until release() or the destructor puts the masks back. A servo thread pinned
/// to a CPU otherwise shares it with the process's other threads (TBB workers, a solver's
/// threads): SCHED_FIFO preempts them, but their memory traffic leaves the servo's caches cold.
/// Threads pinned to that CPU alone are left where they are.
///
/// @par Threading  reserve() on the thread that keeps the CPU; release() from any thread
///      (it looks the threads up again, so a thread that exited meanwhile is skipped). Set-up
///      calls, not real-time: each reads /proc/self/task.
class CpuReservation {
  public:
    CpuReservation() = default;
    ~CpuReservation() { release(); }
    CpuReservation(CpuReservation&& other) noexcept;
    CpuReservation& operator=(CpuReservation&& other) noexcept;
    CpuReservation(const CpuReservation&) = delete;
    CpuReservation& operator=(const CpuReservation&) = delete;

    /// Moves the other threads off @p cpu (the calling thread should be pinned there already).
    /// Nothing moves where @p cpu is the only CPU the process may use.
    /// @throw std::bad_alloc (the list of threads moved).
    static CpuReservation reserve(int cpu);
    /// Restores the masks of the threads still narrowed as reserve() left them, and gives
    /// threads started since with such a mask the mask their parent had. Idempotent.
    void release() noexcept;
    int cpu() const noexcept { return mCpu; }
    std::size_t threadsMoved() const noexcept { return mMoved.size(); }

  private:
    struct Moved {
        pid_t tid;
        cpu_set_t before, after;
    };
    int mCpu = -1;
    std::vector<Moved> mMoved;
};

}  // namespace palp
