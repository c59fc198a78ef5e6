#pragma once
/// @file
/// Internal to first-hit (first_hit.cpp): the bundle without a HitField, eight rays in lockstep
/// per AVX2 step through their block runs.
#include <cstdint>

#include "avx2_util.h"

#ifdef PALP_RAY_AVX2
namespace palp::kernels {

// Internal to the ray kernels (not installed). Helpers are in an anonymous namespace, as they
// were in one source file: each translation unit that includes this keeps its own copies, so the
// compiler inlines them exactly as before.
namespace {  // NOLINT(google-build-namespaces)

/// The bundle's rays eight at a time: every lane holds one ray's pending run, and one AVX2 step
/// takes the next sample of every lane (eight gathers of the cell corners from the padded block
/// copies, the trilinear blend in the same float operations and order as lerp8(), at the same
/// float positions runPos(), so the values are bit-identical to runScalar()'s; no FMA, which
/// would round differently). A lane whose sample lies in a sub-block that cannot reach the
/// threshold jumps instead, as subBlockJump() does. A lane whose run hits or ends goes back to
/// the scalar march (skipping, block entry, refinement) until it has a new run or its ray is
/// done, when the lane takes the bundle's next ray.
__attribute__((target("avx2"))) void traceFirstHitAvx2(const HitContext& cx,
                                                       const RayBundle& bundle,
                                                       BundleHits& out) noexcept {
    constexpr int kLanes = 8;
    const float* const padded = cx.tb->padded;
    HitMarch m[kLanes];
    int ray[kLanes] = {};
    // Per run.
    alignas(32) std::int32_t off[kLanes] = {};   // lane's block copy, floats from `padded`
    alignas(32) std::int32_t idx[kLanes] = {};   // run sample taken next
    alignas(32) std::int32_t last[kLanes] = {};  // runN - 1
    alignas(32) std::int32_t occ[kLanes] = {};   // HitMarch::occ
    alignas(32) std::int32_t pidx[kLanes] = {};  // run sample whose value `prev` holds
    alignas(32) float qx[kLanes] = {}, qy[kLanes] = {}, qz[kLanes] = {};
    alignas(32) float runN[kLanes] = {};
    alignas(32) float prev[kLanes] = {};
    // Per ray.
    alignas(32) float sx[kLanes] = {}, sy[kLanes] = {}, sz[kLanes] = {};
    alignas(32) float ivx[kLanes] = {}, ivy[kLanes] = {}, ivz[kLanes] = {};
    alignas(32) float hix[kLanes] = {}, hiy[kLanes] = {}, hiz[kLanes] = {};
    alignas(32) float farx[kLanes] = {}, fary[kLanes] = {}, farz[kLanes] = {};
    // Per step, for the lanes with events.
    alignas(32) float vNew[kLanes], vOld[kLanes];
    alignas(32) std::int32_t iOld[kLanes], pOld[kLanes];
    unsigned active = 0;
    int next = 0;
    Refinements refs;
    auto loadRay = [&](int l) {
        const HitMarch& h = m[l];
        sx[l] = h.sx;
        sy[l] = h.sy;
        sz[l] = h.sz;
        ivx[l] = h.ivx;
        ivy[l] = h.ivy;
        ivz[l] = h.ivz;
        hix[l] = h.hix;
        hiy[l] = h.hiy;
        hiz[l] = h.hiz;
        farx[l] = h.farx;
        fary[l] = h.fary;
        farz[l] = h.farz;
    };
    auto loadRun = [&](int l) {
        const HitMarch& h = m[l];
        off[l] = static_cast<std::int32_t>(h.base - padded);
        idx[l] = 1;
        last[l] = static_cast<std::int32_t>(h.runN - 1);
        occ[l] = static_cast<std::int32_t>(h.occ);
        pidx[l] = 0;
        qx[l] = h.qx;
        qy[l] = h.qy;
        qz[l] = h.qz;
        runN[l] = static_cast<float>(h.runN);
        prev[l] = h.prev;
    };
    // Gives lane l the next ray that reaches a run (rays that end before are stored).
    auto refill = [&](int l) {
        while (next < out.count) {
            const int i = next++;
            RayHit h;
            m[l].ref = refs.next();
            if (startBundleRay(cx, bundle, i, m[l], h) && advanceHit(cx, m[l], h)) {
                ray[l] = i;
                loadRay(l);
                loadRun(l);
                active |= 1u << l;
                return;
            }
            storeHit(out, i, h);
            if (h.hit && m[l].pending) refs.commit(i);
        }
        // An idle lane reads a valid cell (offset 0, position 0), never jumps and is ignored.
        active &= ~(1u << l);
        off[l] = 0;
        idx[l] = 1;
        last[l] = 1 << 30;
        occ[l] = 0xFF;
        qx[l] = qy[l] = qz[l] = 0;
        sx[l] = sy[l] = sz[l] = 0;
        runN[l] = 0;
    };
    // GCC builds the lambdas' closures above with 256-bit stores and calls the SSE code in
    // refill() without a vzeroupper of its own.
    _mm256_zeroupper();
    for (int l = 0; l < kLanes; ++l) refill(l);
    const __m256i one = _mm256_set1_epi32(1);
    const __m256 thr = _mm256_set1_ps(cx.thr);
    // Bounded: every step takes or passes over at least one sample of every active run, and
    // each ray's samples are bounded as in firstHit().
    while (active != 0) {
        const __m256i ii = loadAvx(idx);
        const __m256 fi = _mm256_cvtepi32_ps(ii);
        const __m256 vqx = _mm256_load_ps(qx), vqy = _mm256_load_ps(qy), vqz = _mm256_load_ps(qz);
        const __m256 vsx = _mm256_load_ps(sx), vsy = _mm256_load_ps(sy), vsz = _mm256_load_ps(sz);
        const __m256 vx = _mm256_add_ps(vqx, _mm256_mul_ps(fi, vsx));
        const __m256 vy = _mm256_add_ps(vqy, _mm256_mul_ps(fi, vsy));
        const __m256 vz = _mm256_add_ps(vqz, _mm256_mul_ps(fi, vsz));
        const __m256i cxi = cellsAvx(vx), cyi = cellsAvx(vy), czi = cellsAvx(vz);
        const __m256i sub = subsAvx(cxi, cyi, czi);
        const __m256i filled =
            _mm256_cmpeq_epi32(_mm256_and_si256(_mm256_srlv_epi32(loadAvx(occ), sub), one), one);
        const unsigned filledBits =
            static_cast<unsigned>(_mm256_movemask_ps(_mm256_castsi256_ps(filled)));
        const __m256 fx = _mm256_sub_ps(vx, _mm256_cvtepi32_ps(cxi));
        const __m256 fy = _mm256_sub_ps(vy, _mm256_cvtepi32_ps(cyi));
        const __m256 fz = _mm256_sub_ps(vz, _mm256_cvtepi32_ps(czi));
        // (cx * 9 + cy) * 9 + cz = 81 cx + 9 cy + cz, by shifts.
        const __m256i c81 = _mm256_add_epi32(
            _mm256_add_epi32(_mm256_slli_epi32(cxi, 6), _mm256_slli_epi32(cxi, 4)), cxi);
        const __m256i c9 = _mm256_add_epi32(_mm256_slli_epi32(cyi, 3), cyi);
        const __m256i at =
            _mm256_add_epi32(loadAvx(off), _mm256_add_epi32(_mm256_add_epi32(c81, c9), czi));
        const __m256 p0 = _mm256_i32gather_ps(padded, at, 4);
        const __m256 p1 = _mm256_i32gather_ps(padded + 1, at, 4);
        const __m256 p9 = _mm256_i32gather_ps(padded + 9, at, 4);
        const __m256 p10 = _mm256_i32gather_ps(padded + 10, at, 4);
        const __m256 p81 = _mm256_i32gather_ps(padded + 81, at, 4);
        const __m256 p82 = _mm256_i32gather_ps(padded + 82, at, 4);
        const __m256 p90 = _mm256_i32gather_ps(padded + 90, at, 4);
        const __m256 p91 = _mm256_i32gather_ps(padded + 91, at, 4);
        const __m256 a00 = lerpAvx(p0, p81, fx), a01 = lerpAvx(p1, p82, fx);
        const __m256 a10 = lerpAvx(p9, p90, fx), a11 = lerpAvx(p10, p91, fx);
        const __m256 b0 = lerpAvx(a00, a10, fy), b1 = lerpAvx(a01, a11, fy);
        const __m256 v = lerpAvx(b0, b1, fz);
        const __m256i inc = _mm256_add_epi32(ii, one);
        __m256i nextIdx = inc;
        if ((~filledBits & active & 0xFFu) != 0) {
            // Jumps (subBlockJump()) for the lanes in sub-blocks that cannot reach the threshold.
            const __m256 ex =
                exitAvx(cxi, _mm256_load_ps(hix), vqx, _mm256_load_ps(ivx), _mm256_load_ps(farx));
            const __m256 ey =
                exitAvx(cyi, _mm256_load_ps(hiy), vqy, _mm256_load_ps(ivy), _mm256_load_ps(fary));
            const __m256 ez =
                exitAvx(czi, _mm256_load_ps(hiz), vqz, _mm256_load_ps(ivz), _mm256_load_ps(farz));
            const __m256 e = _mm256_max_ps(
                _mm256_min_ps(_mm256_min_ps(ex, ey), _mm256_min_ps(ez, _mm256_load_ps(runN))),
                _mm256_setzero_ps());
            const __m256i j = _mm256_max_epi32(inc, _mm256_add_epi32(_mm256_cvttps_epi32(e), one));
            const __m256 fl = _mm256_cvtepi32_ps(_mm256_sub_epi32(j, one));
            const __m256i lsub = subsAvx(cellsAvx(_mm256_add_ps(vqx, _mm256_mul_ps(fl, vsx))),
                                         cellsAvx(_mm256_add_ps(vqy, _mm256_mul_ps(fl, vsy))),
                                         cellsAvx(_mm256_add_ps(vqz, _mm256_mul_ps(fl, vsz))));
            const __m256i jump = _mm256_blendv_epi8(inc, j, _mm256_cmpeq_epi32(lsub, sub));
            nextIdx = _mm256_blendv_epi8(jump, inc, filled);
        }
        const unsigned hitBits =
            static_cast<unsigned>(_mm256_movemask_ps(_mm256_cmp_ps(v, thr, _CMP_GE_OQ))) &
            filledBits;
        const unsigned endBits = static_cast<unsigned>(
            _mm256_movemask_ps(_mm256_castsi256_ps(_mm256_cmpgt_epi32(nextIdx, loadAvx(last)))));
        const __m256 vp = _mm256_load_ps(prev);
        const __m256i pi = loadAvx(pidx);
        _mm256_store_ps(vNew, v);
        _mm256_store_ps(vOld, vp);
        storeAvx(iOld, ii);
        storeAvx(pOld, pi);
        const __m256 filledPs = _mm256_castsi256_ps(filled);
        _mm256_store_ps(prev, _mm256_blendv_ps(vp, v, filledPs));
        storeAvx(pidx, _mm256_blendv_epi8(pi, ii, filled));
        storeAvx(idx, nextIdx);
        const unsigned events = (hitBits | endBits) & active;
        if (events == 0) continue;
        // The scalar march below is SSE code: with dirty upper halves every SSE instruction
        // there would pay a merge with them (measured: the bundle took twice the scalar time).
        _mm256_zeroupper();
        for (unsigned ev = events; ev != 0; ev &= ev - 1) {
            const int l = __builtin_ctz(ev);
            RayHit h;
            m[l].ref = refs.next();
            if ((hitBits >> l) & 1u) {
                const float before = pOld[l] == iOld[l] - 1 ? vOld[l] : runValue(m[l], iOld[l] - 1);
                storeHit(out, ray[l], refineHit(cx, m[l], m[l].runK + iOld[l], before, vNew[l]));
                refs.commit(ray[l]);
            } else if (advanceHit(cx, m[l], h)) {
                loadRun(l);
                continue;
            } else {
                storeHit(out, ray[l], h);
                if (h.hit && m[l].pending) refs.commit(ray[l]);
            }
            refill(l);
        }
    }
    refineAll(cx, refs, out.t.data());
}

}  // namespace

}  // namespace palp::kernels
#endif
