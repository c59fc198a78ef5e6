// Replaces the global allocation functions with counting ones (malloc underneath).
#include "alloc_counter.h"

#include <atomic>
#include <cstdlib>
#include <new>

namespace {
std::atomic<std::uint64_t> gCount{0};
thread_local std::uint64_t tCount = 0;   // trivially initialised: no allocation to reach it
thread_local std::uint64_t tFailAt = 0;  // this thread's count from which operator new fails
thread_local std::uint64_t tFailed = 0;  // allocations made to fail on this thread

/// Counts one allocation; false when it is to fail (failThreadAllocationsFrom).
bool count() noexcept {
    gCount.fetch_add(1, std::memory_order_relaxed);
    ++tCount;
    return tFailAt == 0 || tCount < tFailAt;
}

/// The throwing forms: a failure throws std::bad_alloc.
void countOrThrow() {
    if (count()) return;
    ++tFailed;
    throw std::bad_alloc();
}

void* countedAlloc(std::size_t n) {
    countOrThrow();
    if (void* p = std::malloc(n == 0 ? 1 : n)) return p;
    throw std::bad_alloc();
}

void* countedAlignedAlloc(std::size_t n, std::align_val_t a) {
    countOrThrow();
    const auto al = static_cast<std::size_t>(a);
    const std::size_t size = ((n == 0 ? 1 : n) + al - 1) / al * al;
    if (void* p = std::aligned_alloc(al, size)) return p;
    throw std::bad_alloc();
}
}  // namespace

namespace palp::test {
std::uint64_t allocationCount() noexcept { return gCount.load(std::memory_order_relaxed); }
std::uint64_t threadAllocationCount() noexcept { return tCount; }
void failThreadAllocationsFrom(std::uint64_t n) noexcept { tFailAt = n == 0 ? 0 : tCount + n; }
std::uint64_t threadFailedAllocations() noexcept { return tFailed; }
}  // namespace palp::test

void* operator new(std::size_t n) { return countedAlloc(n); }
void* operator new[](std::size_t n) { return countedAlloc(n); }
void* operator new(std::size_t n, std::align_val_t a) { return countedAlignedAlloc(n, a); }
void* operator new[](std::size_t n, std::align_val_t a) { return countedAlignedAlloc(n, a); }
// The nothrow forms are counted but never made to fail: their callers (std::stable_sort's
// temporary buffer) fall back to another way by contract.
void* operator new(std::size_t n, const std::nothrow_t&) noexcept {
    count();
    return std::malloc(n == 0 ? 1 : n);
}
void* operator new[](std::size_t n, const std::nothrow_t&) noexcept {
    count();
    return std::malloc(n == 0 ? 1 : n);
}
void operator delete(void* p) noexcept { std::free(p); }
void operator delete[](void* p) noexcept { std::free(p); }
void operator delete(void* p, std::size_t) noexcept { std::free(p); }
void operator delete[](void* p, std::size_t) noexcept { std::free(p); }
void operator delete(void* p, std::align_val_t) noexcept { std::free(p); }
void operator delete[](void* p, std::align_val_t) noexcept { std::free(p); }
void operator delete(void* p, std::size_t, std::align_val_t) noexcept { std::free(p); }
void operator delete[](void* p, std::size_t, std::align_val_t) noexcept { std::free(p); }
void operator delete(void* p, const std::nothrow_t&) noexcept { std::free(p); }
void operator delete[](void* p, const std::nothrow_t&) noexcept { std::free(p); }
