#pragma once
/// @file
/// Many bundles at once, TBB-parallel, for offline force maps and studies.

#include <span>

#include "palp/kernels/embree_scene.h"
#include "palp/kernels/volume_ray.h"

namespace palp::kernels {

/// traceFirstHit() for every bundle, in parallel over bundles on the current TBB arena (limit the
/// threads with a tbb::task_arena). Results equal the single-thread path bit for bit.
/// @throw palp::ValueError when @p out is smaller than @p bundles.
/// @par Threading  Call from any thread; parallel inside. Not for the servo thread.
void traceFirstHitBatch(const VolumeView& view, std::span<const RayBundle> bundles,
                        const FirstHitParams& params, std::span<BundleHits> out);

/// traceAccumulate() for every bundle, in parallel. Same rules.
void traceAccumulateBatch(const VolumeView& view, std::span<const RayBundle> bundles,
                          const AccumulateParams& params, std::span<BundleAccumulation> out);

/// traceBundle() against a committed Embree scene for every bundle, in parallel. Same rules.
void traceMeshBatch(const EmbreeScene& scene, std::span<const RayBundle> bundles, unsigned mask,
                    std::span<BundleHits> out);

}  // namespace palp::kernels
