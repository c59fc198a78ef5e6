#pragma once
/// @file
/// palp::parallelFor: tbb::parallel_for with its fork and join edges stated for ThreadSanitizer;
/// palp::arenaExecute: tbb::task_arena::execute likewise.
///
/// Debian's libtbb is not instrumented, so TSan cannot see that a task starts after the caller
/// wrote the data the loop reads (the lambda's captures, output sizes) and that the caller reads
/// the tasks' results only after the join. Without these annotations it reports each such pair
/// (one TBB worker against the calling thread) as a race. They state exactly those two edges and
/// nothing between tasks, so a real race between two tasks is still reported. Outside TSan
/// builds this is tbb::parallel_for.

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <tbb/task_arena.h>

#if defined(__SANITIZE_THREAD__)
#define PALP_TSAN 1
#elif defined(__has_feature)
#if __has_feature(thread_sanitizer)
#define PALP_TSAN 1
#endif
#endif
#ifdef PALP_TSAN
#include <sanitizer/tsan_interface.h>
#endif

namespace palp {

/// tbb::parallel_for(range, body), body(const Range&) called on sub-ranges.
template <class Range, class Body>
void parallelFor(const Range& range, const Body& body) {
#ifdef PALP_TSAN
    char fork = 0, join = 0;  // addresses only: the sync objects of the two edges
    __tsan_release(&fork);
    tbb::parallel_for(range, [&](const Range& r) {
        __tsan_acquire(&fork);
        body(r);
        __tsan_release(&join);
    });
    __tsan_acquire(&join);
#else
    tbb::parallel_for(range, body);
#endif
}

/// f(i) for every i in [first, last), in parallel (grain: TBB's automatic partitioner, or
/// @p grain indices per task when > 0).
template <class Index, class F>
void parallelForEach(Index first, Index last, const F& f, Index grain = 0) {
    if (!(first < last)) return;
    const tbb::blocked_range<Index> range =
        grain > 0 ? tbb::blocked_range<Index>(first, last, static_cast<std::size_t>(grain))
                  : tbb::blocked_range<Index>(first, last);
    parallelFor(range, [&](const tbb::blocked_range<Index>& r) {
        for (Index i = r.begin(); i != r.end(); ++i) f(i);
    });
}

/// arena.execute(f) with its two edges stated for ThreadSanitizer: what the caller did before
/// happens before f, and what f did (on whichever thread TBB ran it: the caller, or one of the
/// arena's workers while the caller waits) happens before the return. Objects f allocates on a
/// worker and the caller frees later are then no race to TSan.
template <class F>
void arenaExecute(tbb::task_arena& arena, const F& f) {
#ifdef PALP_TSAN
    char fork = 0, join = 0;  // addresses only: the sync objects of the two edges
    __tsan_release(&fork);
    arena.execute([&] {
        __tsan_acquire(&fork);
        f();
        __tsan_release(&join);
    });
    __tsan_acquire(&join);
#else
    arena.execute(f);
#endif
}

}  // namespace palp
