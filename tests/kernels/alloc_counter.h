#pragma once
// A counting global operator new (defined in alloc_counter.cpp) for the zero-allocation tests.
#include <cstdint>

namespace palp::test {
/// Number of operator new calls in this process so far (all threads).
std::uint64_t allocationCount() noexcept;
}  // namespace palp::test
