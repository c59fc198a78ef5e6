#pragma once
// The process's memory as the kernel counts it, for the peak-memory tests.
#include <utility>

namespace palp::test {

/// Resident set size now and its peak since the last reset (bytes), from /proc/self/status
/// (VmRSS, VmHWM; `std::ofstream("/proc/self/clear_refs") << "5"` resets the peak).
std::pair<double, double> rssAndPeak();

}  // namespace palp::test
