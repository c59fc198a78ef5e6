#pragma once
// A counting global operator new (defined in alloc_counter.cpp) for the zero-allocation tests.
#include <cstdint>

namespace palp::test {
/// Number of operator new calls in this process so far (all threads).
std::uint64_t allocationCount() noexcept;
/// Number of operator new calls made by the calling thread so far: what a real-time thread
/// (the servo's ticks) allocates, whatever other threads (a secondary building layouts) do.
std::uint64_t threadAllocationCount() noexcept;
/// Fault injection: from the calling thread's @p n-th operator new from now (1-based), every
/// throwing operator new on this thread throws std::bad_alloc, until called with 0 (the nothrow
/// forms are counted, never failed). Other threads allocate as usual (a set-up that runs out
/// of memory on the host's thread).
void failThreadAllocationsFrom(std::uint64_t n) noexcept;
/// Allocations failThreadAllocationsFrom made to fail on the calling thread so far.
std::uint64_t threadFailedAllocations() noexcept;
}  // namespace palp::test
