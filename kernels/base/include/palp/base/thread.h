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

}  // namespace palp
