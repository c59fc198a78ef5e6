#include "palp/kernels/ray_batch.h"

#include <string>

#include "palp/base/parallel.h"
#include "palp/base/validate.h"

namespace palp::kernels {

namespace {
void checkSizes(std::size_t bundles, std::size_t out) {
    if (out < bundles)
        throwExpected("ray batch output", "room for " + std::to_string(bundles) + " bundles",
                      std::to_string(out));
}

template <class F>
void forEach(std::size_t n, F&& f) {
    parallelForEach(std::size_t{0}, n, f, std::size_t{16});
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
