#pragma once
/// @file
/// Internal to first-hit (first_hit.cpp): the march without a HitField, block run by block
/// run (skipping blocks and 4^3 sub-blocks that cannot reach the threshold), and the prefetch of
/// a bundle's path.
#include <cstdint>

#include "hit_march.h"

namespace palp::kernels {

// Internal to the ray kernels (not installed). Helpers are in an anonymous namespace, as they
// were in one source file: each translation unit that includes this keeps its own copies, so the
// compiler inlines them exactly as before.
namespace {  // NOLINT(google-build-namespaces)

/// Bit s set where sub-block s of the padded copy at @p base may reach @p thr.
PALP_HOT unsigned occupancy(const Table& tb, const float* base, float thr) noexcept {
    const auto copy = static_cast<std::size_t>(base - tb.padded) / Table::kPadded;
    const float* b = tb.subMax + copy * Table::kSubBlocks;
#if defined(__SSE2__) && defined(__x86_64__)
    const __m128 t = _mm_set1_ps(thr);
    // _CMP_GE_OQ as in the scalar test: NaN bounds never occur (see the view's set-up).
    const int lo = _mm_movemask_ps(_mm_cmpge_ps(_mm_loadu_ps(b), t));
    const int hi = _mm_movemask_ps(_mm_cmpge_ps(_mm_loadu_ps(b + 4), t));
    return static_cast<unsigned>(lo | (hi << 4));
#else
    unsigned occ = 0;
    for (int s = 0; s < Table::kSubBlocks; ++s)
        if (b[s] >= thr) occ |= 1u << s;
    return occ;
#endif
}

/// Marches from sample m.k until the ray ends (false, @p out set) or reaches a run of at least
/// one more float-placed sample inside a block (true, the run set in @p m).
bool advanceHit(const HitContext& cx, HitMarch& m, RayHit& out) noexcept {
    const Table& tb = *cx.tb;
    const IndexRay& r = m.r;
    const float thr = cx.thr;
    Cell c;
    for (std::int64_t k = m.k; k <= r.kEnd;) {
        const double t = r.t(k);
        const double xr = m.ox + t * r.d[0], yr = m.oy + t * r.d[1], zr = m.oz + t * r.d[2];
        if (xr >= 0 && xr < cx.limX && yr >= 0 && yr < cx.limY && zr >= 0 && zr < cx.limZ)
            [[likely]] {
            const auto ix = static_cast<std::int32_t>(xr), iy = static_cast<std::int32_t>(yr),
                       iz = static_cast<std::int32_t>(zr);
            const std::int64_t b = ((ix >> 3) * cx.nby + (iy >> 3)) * cx.nbz + (iz >> 3);
            if (cx.skip && tb.maxDilated[static_cast<std::size_t>(b)] < thr) {
                c.ix = ix;
                c.iy = iy;
                c.iz = iz;
                c.block = b;
                k = skipBlocks(tb, r, c, k, [thr](float mx, float) { return mx < thr; });
                continue;
            }
            if (k <= m.kRunLast) {
                // The first sample of the run on its exact position (a run often ends right
                // there: a hit at the first sample after skipped blocks).
                const float* base = tb.data[static_cast<std::size_t>(b)];
                const float v = lerp8(base + (((ix & 7) * 9 + (iy & 7)) * 9 + (iz & 7)),
                                      static_cast<float>(xr - ix), static_cast<float>(yr - iy),
                                      static_cast<float>(zr - iz));
                if (v >= thr) {
                    out = hitAtSample(cx, m, k, v);
                    return false;
                }
                // The rest of the run through this block: block-local float positions
                // q + float(i) s (runPos()), from q recomputed exactly at every block entry
                // (error below 1e-5 voxel). The run ends at the block's exit; a sample
                // that rounding puts a hair past the exit still reads its cell through the clamp
                // in the run loop (the 9^3 copy holds the +1 layer), and one the run leaves out
                // is simply the first of the next run.
                const double lx = xr - (ix & ~7), ly = yr - (iy & ~7), lz = zr - (iz & ~7);
                const double tRel = std::min(std::min((m.face[0] - lx) * m.invF[0] + m.far[0],
                                                      (m.face[1] - ly) * m.invF[1] + m.far[1]),
                                             (m.face[2] - lz) * m.invF[2] + m.far[2]);
                // At most ~28 samples fit in a block (0.5-voxel steps), far below kMaxSamples.
                const double more = std::min(tRel * r.invStep, static_cast<double>(m.kRunLast - k));
                const std::int64_t n = 1 + static_cast<std::int64_t>(more);
                if (n == 1) {
                    ++k;
                    continue;
                }
                m.base = base;
                m.qx = static_cast<float>(lx);
                m.qy = static_cast<float>(ly);
                m.qz = static_cast<float>(lz);
                m.occ = cx.skip ? occupancy(tb, base, thr) : 0xFFu;
                m.prev = v;
                m.runK = k;
                m.runN = n;
                m.k = k + n;
                return true;
            }
        }
        // The last sample (cut to the length), outside the table (background) or non-finite:
        // the general path.
        locate(tb, r.o[0] + t * r.d[0], r.o[1] + t * r.d[1], r.o[2] + t * r.d[2], c);
        const float v = sampleCell(tb, cx.bg, c);
        if (v >= thr) {
            out = hitAtSample(cx, m, k, v);
            return false;
        }
        ++k;
    }
    out = noHit(r.length);
    return false;
}

/// Sub-block index (0..7) of a cell of a padded copy.
PALP_HOT unsigned subBlock(unsigned cx0, unsigned cy0, unsigned cz0) noexcept {
    return ((cx0 >> 2) << 2) | ((cy0 >> 2) << 1) | (cz0 >> 2);
}

/// The value of run sample @p i of @p m (the run's first sample for i = 0).
PALP_HOT float runValue(const HitMarch& m, std::int64_t i) noexcept {
    if (i == 0) return m.prev;
    const float px = runPos(m.qx, m.sx, i), py = runPos(m.qy, m.sy, i), pz = runPos(m.qz, m.sz, i);
    const unsigned cx0 = runCell(px), cy0 = runCell(py), cz0 = runCell(pz);
    return lerp8(m.base + ((cx0 * 9 + cy0) * 9 + cz0), px - static_cast<float>(cx0),
                 py - static_cast<float>(cy0), pz - static_cast<float>(cz0));
}

/// The next run sample to take after sample @p i, which lies in cell (cx0, cy0, cz0) of a
/// sub-block that cannot reach the threshold: the first sample estimated past that sub-block
/// (at most runN), or i + 1 when the samples in between are not all provably inside it. The
/// last sample passed over is checked on its exact float position (positions are monotone in
/// i along every axis, so the ones between lie in the sub-block too), so an estimate that
/// rounding puts one sample too far only costs the jump, never a skipped sample.
PALP_HOT std::int64_t subBlockJump(const HitMarch& m, std::int64_t i, unsigned cx0, unsigned cy0,
                                   unsigned cz0) noexcept {
    const float ex = (static_cast<float>((cx0 >> 2) * 4) + m.hix - m.qx) * m.ivx + m.farx;
    const float ey = (static_cast<float>((cy0 >> 2) * 4) + m.hiy - m.qy) * m.ivy + m.fary;
    const float ez = (static_cast<float>((cz0 >> 2) * 4) + m.hiz - m.qz) * m.ivz + m.farz;
    const float e = std::min(std::min(ex, ey), std::min(ez, static_cast<float>(m.runN)));
    const std::int64_t j = std::max(i + 1, static_cast<std::int64_t>(std::max(e, 0.0f)) + 1);
    if (j - 1 == i) return j;
    const std::int64_t l = j - 1;  // the last sample passed over
    const unsigned lx = runCell(runPos(m.qx, m.sx, l)), ly = runCell(runPos(m.qy, m.sy, l)),
                   lz = runCell(runPos(m.qz, m.sz, l));
    return subBlock(lx, ly, lz) == subBlock(cx0, cy0, cz0) ? j : i + 1;
}

/// The pending run of @p m, one ray at a time: true (and @p out set) on a hit. Samples in
/// sub-blocks that cannot reach the threshold are passed over; a hit whose predecessor was
/// passed over reads it then (the same float position, so the same value as when taken).
bool runScalar(const HitContext& cx, HitMarch& m, RayHit& out) noexcept {
    float vPrev = m.prev;
    std::int64_t iPrev = 0;
    for (std::int64_t i = 1; i < m.runN;) {
        const float px = runPos(m.qx, m.sx, i), py = runPos(m.qy, m.sy, i),
                    pz = runPos(m.qz, m.sz, i);
        const unsigned cx0 = runCell(px), cy0 = runCell(py), cz0 = runCell(pz);
        if (!((m.occ >> subBlock(cx0, cy0, cz0)) & 1u)) {
            i = subBlockJump(m, i, cx0, cy0, cz0);
            continue;
        }
        const float v = lerp8(m.base + ((cx0 * 9 + cy0) * 9 + cz0), px - static_cast<float>(cx0),
                              py - static_cast<float>(cy0), pz - static_cast<float>(cz0));
        if (v >= cx.thr) {
            out = refineHit(cx, m, m.runK + i, iPrev == i - 1 ? vPrev : runValue(m, i - 1), v);
            return true;
        }
        vPrev = v;
        iPrev = i;
        ++i;
    }
    return false;
}

PALP_HOT void storeHit(BundleHits& out, int i, const RayHit& h) noexcept {
    const auto r = static_cast<std::size_t>(i);
    out.t[r] = h.t;
    out.hit[r] = h.hit ? 1 : 0;
    out.geomId[r] = 0;
}

PALP_HOT bool startBundleRay(const HitContext& cx, const RayBundle& bundle, int i, HitMarch& m,
                             RayHit& out) noexcept {
    const auto r = static_cast<std::size_t>(i);
    return startHit(cx, Eigen::Vector3d(bundle.ox[r], bundle.oy[r], bundle.oz[r]),
                    Eigen::Vector3d(bundle.dx[r], bundle.dy[r], bundle.dz[r]), bundle.length[r], m,
                    out);
}

/// Starts the loads of the data the bundle's first ray will read, at about one point per voxel
/// along it (the block table entries, then the copy lines and cell masks of its blocks),
/// so that cache misses at positions no earlier frame touched overlap instead of following one
/// another block by block. The other rays of a bundle leave from the same proxy within a few
/// degrees and mostly read the same blocks. No effect on results.
void prefetchPath(const HitContext& cx, const RayBundle& bundle) noexcept {
    if (bundle.count < 1 || !cx.usable) return;
    const Table& tb = *cx.tb;
    const double dx = bundle.dx[0], dy = bundle.dy[0], dz = bundle.dz[0];
    const double n = std::sqrt(dx * dx + dy * dy + dz * dz);
    const double len = bundle.length[0];
    if (!(n > 0) || !(len >= 0) || !(len < 1e3)) return;
    const Eigen::Vector3d o =
        cx.view->indexFromWorld(Eigen::Vector3d(bundle.ox[0], bundle.oy[0], bundle.oz[0]));
    // One point per voxel along the ray (a 10 mm ray at 0.5 mm voxels: 21 points); each block
    // the points enter once, with the cells of its first and last point.
    constexpr int kMaxPoints = 33;
    const double voxels = len * cx.view->inverseVoxelSize();
    const int points = std::clamp(static_cast<int>(voxels) + 1, 2, kMaxPoints);
    const double sc = voxels / ((points - 1) * n);
    const double ex = sc * dx, ey = sc * dy, ez = sc * dz;
    double x = o.x() - tb.origin[0], y = o.y() - tb.origin[1], z = o.z() - tb.origin[2];
    std::int64_t blocks[kMaxPoints];
    std::int32_t first[kMaxPoints], last[kMaxPoints];
    int count = 0;
    for (int q = 0; q < points; ++q, x += ex, y += ey, z += ez) {
        if (!((x >= 0) & (x < cx.limX) & (y >= 0) & (y < cx.limY) & (z >= 0) & (z < cx.limZ)))
            continue;
        const auto ix = static_cast<std::int32_t>(x), iy = static_cast<std::int32_t>(y),
                   iz = static_cast<std::int32_t>(z);
        const std::int64_t b = ((ix >> 3) * cx.nby + (iy >> 3)) * cx.nbz + (iz >> 3);
        const std::int32_t cell = ((ix & 7) * 9 + (iy & 7)) * 9 + (iz & 7);
        if (count > 0 && blocks[count - 1] == b) {
            last[count - 1] = cell;
            continue;
        }
        __builtin_prefetch(&tb.maxDilated[static_cast<std::size_t>(b)]);
        __builtin_prefetch(&tb.data[static_cast<std::size_t>(b)]);
        if (cx.field != nullptr)
            __builtin_prefetch(cx.field->entries() + static_cast<std::size_t>(b));
        blocks[count] = b;
        first[count] = last[count] = cell;
        ++count;
    }
    // Second pass, once the table entries are on their way: the copy lines around the first and
    // last cells, and the field's cell masks, of the blocks that cannot be skipped.
    for (int q = 0; q < count; ++q) {
        const auto b = static_cast<std::size_t>(blocks[q]);
        if (tb.maxDilated[b] < cx.thr) continue;
        const float* base = tb.data[b];
        for (const std::int32_t c : {first[q], last[q]}) {
            __builtin_prefetch(base + c);
            __builtin_prefetch(base + c + 10);
            __builtin_prefetch(base + c + 81);
            __builtin_prefetch(base + c + 91);
        }
        if (cx.field != nullptr) {
            // The mask, and the per-mask copy offset and pointer that a blend reads between
            // the entry and the copy (otherwise one more dependent miss per block).
            const std::uint32_t mask = cx.field->entry(b) >> HitField::kDistanceBits;
            __builtin_prefetch(cx.field->masks() + mask * HitField::kMaskWords);
            __builtin_prefetch(cx.field->maskCopyOffsets() + mask);
            __builtin_prefetch(cx.field->maskCopies() + mask);
        }
    }
}

}  // namespace

}  // namespace palp::kernels
