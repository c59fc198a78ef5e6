#pragma once
// A counting global operator new (defined in alloc_counter.cpp) for the zero-allocation tests.
#include <cstdint>

namespace palp::test {
/// Number of operator new calls in this process so far (all threads).
std::uint64_t allocationCount() noexcept;
/// Number of operator new calls made by the calling thread so far: what a real-time thread
/// (the servo's ticks) allocates, whatever other threads (a secondary building layouts) do.
std::uint64_t threadAllocationCount() noexcept;
}  // namespace palp::test
