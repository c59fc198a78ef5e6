// Heap settings for palp's batch commands.
#include "batch_heap.h"

#include <malloc.h>
#include <sys/mman.h>
#include <unistd.h>

#include <cstdint>
#include <cstdlib>
#include <thread>

namespace palp::tool {

namespace {

/// glibc arenas of a live session: 1 kept the regions' resident set flat over a 7-minute soak
/// where glibc's default (8 a core) let it creep 3 % in 17 minutes and 2 arenas 3.5 % in 5
/// (bench_soak on the bone phantom's regions).
constexpr int kLiveArenas = 1;

/// The grid's leaves (2 KB each, hundreds of MB) are faulted in page by page: with 4 KB pages
/// the faults and glibc's malloc on fresh pages were about a quarter of convert's CPU samples
/// (head CT at 0.5 mm, perf; 47,000 faults, 4,300 with huge pages). glibc backs its heap with
/// transparent huge pages only when asked at start-up (GLIBC_TUNABLES), so the heap is reserved
/// here: every thread allocates from the main arena, whose top grows 1 GiB at a time (address space
/// only: untouched pages cost nothing), and that range is marked for huge pages (the kernel's THP
/// mode "madvise", Debian's default). Without THP the madvise fails and nothing else changes.
/// One arena means one lock for every leaf allocated: that was measured on 2 cores only, so a
/// machine with more than 4 keeps glibc's per-thread arenas (and 4 KB pages).
void hugePageHeap() {
    if (std::thread::hardware_concurrency() > 4) return;
    mallopt(M_ARENA_MAX, 1);
    mallopt(M_TOP_PAD, 1 << 30);
    void* probe = std::malloc(16 << 20);  // below the mmap threshold: grows the heap top
    const auto begin = reinterpret_cast<std::uintptr_t>(probe);
    const auto end = reinterpret_cast<std::uintptr_t>(sbrk(0));
    constexpr std::uintptr_t kHuge = std::uintptr_t{2} << 20;
    const std::uintptr_t from = (begin + kHuge - 1) & ~(kHuge - 1);
    if (probe && end > from + kHuge)
        madvise(reinterpret_cast<void*>(from), (end - from) & ~(kHuge - 1), MADV_HUGEPAGE);
    std::free(probe);
}

}  // namespace

void liveHeap() { mallopt(M_ARENA_MAX, kLiveArenas); }

void batchHeap() {
    // A batch job that reads hundreds of files: freed buffers stay in the heap for the next
    // file instead of going back to the kernel (glibc trims the heap top and unmaps blocks over
    // its mmap threshold, so each file's pixel buffers were faulted in anew). An 800-file
    // series: 1.2 -> 0.8 s CPU per 100 files on a 2-vCPU VM.
    mallopt(M_MMAP_THRESHOLD, 32 << 20);
    mallopt(M_TRIM_THRESHOLD, 1 << 30);
    hugePageHeap();
}

}  // namespace palp::tool
