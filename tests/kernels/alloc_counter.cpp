// Replaces the global allocation functions with counting ones (malloc underneath).
#include "alloc_counter.h"

#include <atomic>
#include <cstdlib>
#include <new>

namespace {
std::atomic<std::uint64_t> gCount{0};
thread_local std::uint64_t tCount = 0;  // trivially initialised: no allocation to reach it

void* countedAlloc(std::size_t n) {
    gCount.fetch_add(1, std::memory_order_relaxed);
    ++tCount;
    if (void* p = std::malloc(n == 0 ? 1 : n)) return p;
    throw std::bad_alloc();
}

void* countedAlignedAlloc(std::size_t n, std::align_val_t a) {
    gCount.fetch_add(1, std::memory_order_relaxed);
    ++tCount;
    const auto al = static_cast<std::size_t>(a);
    const std::size_t size = ((n == 0 ? 1 : n) + al - 1) / al * al;
    if (void* p = std::aligned_alloc(al, size)) return p;
    throw std::bad_alloc();
}
}  // namespace

namespace palp::test {
std::uint64_t allocationCount() noexcept { return gCount.load(std::memory_order_relaxed); }
std::uint64_t threadAllocationCount() noexcept { return tCount; }
}  // namespace palp::test

void* operator new(std::size_t n) { return countedAlloc(n); }
void* operator new[](std::size_t n) { return countedAlloc(n); }
void* operator new(std::size_t n, std::align_val_t a) { return countedAlignedAlloc(n, a); }
void* operator new[](std::size_t n, std::align_val_t a) { return countedAlignedAlloc(n, a); }
void* operator new(std::size_t n, const std::nothrow_t&) noexcept {
    gCount.fetch_add(1, std::memory_order_relaxed);
    ++tCount;
    return std::malloc(n == 0 ? 1 : n);
}
void* operator new[](std::size_t n, const std::nothrow_t&) noexcept {
    gCount.fetch_add(1, std::memory_order_relaxed);
    ++tCount;
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
