#include "palp/kernels/ray_batch.h"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <string>

#include "palp/error.h"

// ThreadSanitizer cannot see the fork and join edges of Debian's libtbb (it is not
// instrumented), so it would report every read a task makes of data the caller wrote before the
// loop, and every read the caller makes of the results afterwards. The annotations below state
// exactly those two edges, and nothing between tasks, so races between tasks stay visible.
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

namespace palp::kernels {

namespace {
void checkSizes(std::size_t bundles, std::size_t out) {
    if (out < bundles)
        throw ValueError("ray batch output: expected room for " + std::to_string(bundles) +
                         " bundles, found " + std::to_string(out));
}

template <class F>
void forEach(std::size_t n, F&& f) {
#ifdef PALP_TSAN
    char fork = 0, join = 0;  // addresses only: the sync objects of the two edges
    __tsan_release(&fork);
#endif
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, n, 16),
                      [&](const tbb::blocked_range<std::size_t>& r) {
#ifdef PALP_TSAN
                          __tsan_acquire(&fork);
#endif
                          for (std::size_t i = r.begin(); i != r.end(); ++i) f(i);
#ifdef PALP_TSAN
                          __tsan_release(&join);
#endif
                      });
#ifdef PALP_TSAN
    __tsan_acquire(&join);
#endif
}
}  // namespace

void traceFirstHitBatch(const VolumeView& view, std::span<const RayBundle> bundles,
                        const FirstHitParams& params, std::span<BundleHits> out) {
    checkSizes(bundles.size(), out.size());
    forEach(bundles.size(),
            [&](std::size_t i) { traceFirstHit(view, bundles[i], params, out[i]); });
}

void traceAccumulateBatch(const VolumeView& view, std::span<const RayBundle> bundles,
                          const AccumulateParams& params, std::span<BundleAccumulation> out) {
    checkSizes(bundles.size(), out.size());
    forEach(bundles.size(),
            [&](std::size_t i) { traceAccumulate(view, bundles[i], params, out[i]); });
}

void traceMeshBatch(const EmbreeScene& scene, std::span<const RayBundle> bundles, unsigned mask,
                    std::span<BundleHits> out) {
    checkSizes(bundles.size(), out.size());
    forEach(bundles.size(), [&](std::size_t i) { traceBundle(scene, bundles[i], mask, out[i]); });
}

}  // namespace palp::kernels
