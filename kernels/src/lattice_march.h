#pragma once
/// @file
/// Internal to first-hit (first_hit.cpp): the HitField path's sample lattice of one ray and its
/// scalar march.
#include <cstdint>

#include "block_march.h"

namespace palp::kernels {

// Internal to the ray kernels (not installed). Helpers are in an anonymous namespace, as they
// were in one source file: each translation unit that includes this keeps its own copies, so the
// compiler inlines them exactly as before.
namespace {  // NOLINT(google-build-namespaces)

/// The HitField path's sample lattice of one ray: the samples k = kA .. kA + n - 1 (every
/// sample before the ray's cut last one that lies in the table's interior) at table-relative
/// float positions q + float(i) s, i = k - kA, from q taken exactly (double) at sample kA.
/// Unlike the block runs there is no exact re-anchoring per block, so a sample sits within about
/// 5e-4 voxel of o + t_k d (1e-5 in the block runs) and results agree with the other paths to
/// that rounding, not bit for bit.
struct Lattice {
    float qx = 0, qy = 0, qz = 0, sx = 0, sy = 0, sz = 0;
    float invSmax = 0;  // 1 / the largest |s| component (voxels per sample)
    std::int64_t kA = 0;
    std::int32_t n = 0;
};

PALP_HOT void startLattice(const HitMarch& m, Lattice& l) noexcept {
    const IndexRay& r = m.r;
    l.kA = r.kBegin;
    // At most kMaxSamplesPerRay samples.
    l.n = static_cast<std::int32_t>(
        std::max<std::int64_t>(0, std::min(r.kEnd, r.kLast - 1) - r.kBegin + 1));
    const double t = static_cast<double>(l.kA) * r.step;
    l.qx = static_cast<float>(m.ox + t * r.d[0]);
    l.qy = static_cast<float>(m.oy + t * r.d[1]);
    l.qz = static_cast<float>(m.oz + t * r.d[2]);
    l.sx = m.sx;
    l.sy = m.sy;
    l.sz = m.sz;
    const float smax = std::max({std::fabs(l.sx), std::fabs(l.sy), std::fabs(l.sz)});
    l.invSmax = smax > 0 ? 1.0f / smax : 0.0f;
}

/// A hit at lattice sample i (value v) whose predecessor's value is @p vPrev: records the
/// refinement (lattice probes) and returns the provisional hit.
PALP_HOT RayHit latticeHit(const HitContext& cx, HitMarch& m, const Lattice& l, std::int32_t i,
                           float vPrev, float v) noexcept {
    recordFloatRefinement(cx, m, true, nullptr, l.qx, l.qy, l.qz, static_cast<double>(l.kA), i,
                          vPrev, v);
    return {static_cast<float>(m.r.t(l.kA + i)), true};
}

/// A hit at lattice sample i: at the lattice's first sample the predecessor lies outside the
/// table's interior (or before the ray), and is read on its exact position as after skipped
/// blocks; otherwise it is the lattice sample i - 1 (its value @p vPrev when @p known).
PALP_HOT RayHit latticeHitAt(const HitContext& cx, HitMarch& m, const Lattice& l, std::int32_t i,
                             bool known, float vPrev, float v) noexcept {
    if (i == 0) return hitAtSample(cx, m, l.kA, v);
    const auto fp = static_cast<float>(i - 1);
    const float before =
        known ? vPrev : latticeValue(cx, l.qx + fp * l.sx, l.qy + fp * l.sy, l.qz + fp * l.sz);
    return latticeHit(cx, m, l, i, before, v);
}

/// After the lattice: the ray's cut last sample (t = length) when it lies in the table, on its
/// exact position.
PALP_HOT RayHit latticeEnd(const HitContext& cx, HitMarch& m, const Lattice& l) noexcept {
    const IndexRay& r = m.r;
    if (r.kEnd >= r.kLast && r.kLast >= l.kA + l.n) {
        // Its cell's field bit first (it lies in the table's interior).
        const double t = r.t(r.kLast);
        const double x = m.ox + t * r.d[0], y = m.oy + t * r.d[1], z = m.oz + t * r.d[2];
        const unsigned ux = std::min(static_cast<unsigned>(std::max(0.0, x)), cx.cellMax[0]);
        const unsigned uy = std::min(static_cast<unsigned>(std::max(0.0, y)), cx.cellMax[1]);
        const unsigned uz = std::min(static_cast<unsigned>(std::max(0.0, z)), cx.cellMax[2]);
        const std::size_t b = (ux >> 3) * cx.strideX + (uy >> 3) * cx.strideY + (uz >> 3);
        if (cx.field->cellCanReach(b, ((ux & 7) * 8 + (uy & 7)) * 8 + (uz & 7))) {
            CornerCache cache;
            const float v = sampleAt(*cx.view, r, t, cache);
            if (v >= cx.thr) return hitAtSample(cx, m, r.kLast, v);
        }
    }
    return noHit(r.length);
}

/// How many lattice samples after sample i certainly lie in blocks with no cell that can reach
/// the threshold, when sample i's block is at HitField::blockDistance() @p dBlocks: a point
/// within Chebyshev distance r of sample i lies in a block at most ceil(r / 8) away, so the
/// samples within 8 (dBlocks - 1) voxels do (less a margin far above the float error of the
/// positions). 0 for dBlocks < 2.
PALP_HOT std::int32_t latticeColdRun(const Lattice& l, unsigned dBlocks) noexcept {
    if (dBlocks < 2) return 0;
    const float m = (8.0f * static_cast<float>(dBlocks - 1) - 0.01f) * l.invSmax;
    return m < static_cast<float>(l.n) ? static_cast<std::int32_t>(m) : l.n;
}

/// The HitField march of one ray (after startHit()), one sample at a time: each sample's cell,
/// its block and the field's bit there; the blend only where the bit is set.
RayHit marchLatticeScalar(const HitContext& cx, HitMarch& m) noexcept {
    Lattice l;
    startLattice(m, l);
    const HitField& field = *cx.field;
    float vPrev = 0;
    std::int32_t iPrev = -1;
    for (std::int32_t i = 0; i < l.n; ++i) {
        const auto fi = static_cast<float>(i);
        const float px = l.qx + fi * l.sx, py = l.qy + fi * l.sy, pz = l.qz + fi * l.sz;
        const unsigned ux = std::min(static_cast<unsigned>(static_cast<int>(px)), cx.cellMax[0]);
        const unsigned uy = std::min(static_cast<unsigned>(static_cast<int>(py)), cx.cellMax[1]);
        const unsigned uz = std::min(static_cast<unsigned>(static_cast<int>(pz)), cx.cellMax[2]);
        const std::size_t b = (ux >> 3) * cx.strideX + (uy >> 3) * cx.strideY + (uz >> 3);
        if (const unsigned dBlocks = field.blockDistance(b); dBlocks != 0) {
            i += latticeColdRun(l, dBlocks);  // and the loop's 1
            continue;
        }
        if (!field.cellCanReach(b, ((ux & 7) * 8 + (uy & 7)) * 8 + (uz & 7))) continue;
        const float* copy = field.maskCopy(field.entry(b) >> HitField::kDistanceBits);
        const float v =
            lerp8(copy + (((ux & 7) * 9 + (uy & 7)) * 9 + (uz & 7)), px - static_cast<float>(ux),
                  py - static_cast<float>(uy), pz - static_cast<float>(uz));
        if (v >= cx.thr) return latticeHitAt(cx, m, l, i, iPrev == i - 1, vPrev, v);
        vPrev = v;
        iPrev = i;
    }
    return latticeEnd(cx, m, l);
}

}  // namespace

}  // namespace palp::kernels
