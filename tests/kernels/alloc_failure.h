#pragma once
// Set-up under allocation failure (issue 38): build something once for each failure point of
// the calling thread's allocations, with the counting operator new of alloc_counter.cpp.
#include <gtest/gtest.h>

#include <algorithm>
#include <cstdint>
#include <new>

#include "alloc_counter.h"

namespace palp::test {

/// Calls @p build() for about @p points failure points k spread over 1..@p total (the calling
/// thread's k-th allocation from the call on, and every later one, throw std::bad_alloc). Each
/// call must either throw std::bad_alloc or, when it builds, have made no throwing allocation
/// fail (the last allocations may be nothrow ones, e.g. a sort's buffer, which fall back
/// without one): a failure it swallowed is a test failure. Returns how many calls threw.
template <class Build>
int buildUnderEachAllocationFailure(std::uint64_t total, std::uint64_t points, Build build) {
    const std::uint64_t step = std::max<std::uint64_t>(1, total / points);
    int thrown = 0;
    for (std::uint64_t k = 1; k <= total; k += step) {
        const std::uint64_t failedBefore = threadFailedAllocations();
        failThreadAllocationsFrom(k);
        try {
            build();
            failThreadAllocationsFrom(0);
            EXPECT_EQ(threadFailedAllocations(), failedBefore)
                << "a failed allocation was swallowed (from " << k << " of " << total << ")";
        } catch (const std::bad_alloc&) {
            failThreadAllocationsFrom(0);
            ++thrown;
        }
    }
    return thrown;
}

}  // namespace palp::test
