#pragma once
/// @file
/// Internal to first-hit (first_hit.cpp): the HitField lattice march eight samples per AVX2
/// step, the bundle's vector ray set-up (four rays per step) and the field bundle trace.
#include <cstdint>
#include <new>

#include "avx2_util.h"

#ifdef PALP_RAY_AVX2
namespace palp::kernels {

// Internal to the ray kernels (not installed). Helpers are in an anonymous namespace, as they
// were in one source file: each translation unit that includes this keeps its own copies, so the
// compiler inlines them exactly as before.
namespace {  // NOLINT(google-build-namespaces)

/// marchLatticeScalar() eight samples at a time: the cells, blocks (one gather of the field's
/// block entries, one of their mask words) of samples i .. i + 7 in one step, at the same float
/// positions, and the scalar blend only at samples whose bit is set, in
/// order. Bit-identical to marchLatticeScalar().
__attribute__((target("avx2"), always_inline)) inline RayHit marchLatticeAvx2(
    const HitContext& cx, HitMarch& m, const Lattice& l) noexcept {
    const HitField& field = *cx.field;
    const __m256 qx = _mm256_set1_ps(l.qx), qy = _mm256_set1_ps(l.qy), qz = _mm256_set1_ps(l.qz);
    const __m256 sx = _mm256_set1_ps(l.sx), sy = _mm256_set1_ps(l.sy), sz = _mm256_set1_ps(l.sz);
    const __m256i lane = _mm256_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7);
    const __m256i seven = _mm256_set1_epi32(7);
    const __m256i mx = _mm256_set1_epi32(static_cast<int>(cx.cellMax[0]));
    const __m256i my = _mm256_set1_epi32(static_cast<int>(cx.cellMax[1]));
    const __m256i mz = _mm256_set1_epi32(static_cast<int>(cx.cellMax[2]));
    const __m256i strideX = _mm256_set1_epi32(static_cast<int>(cx.strideX));
    const __m256i strideY = _mm256_set1_epi32(static_cast<int>(cx.strideY));
    const auto* entries = reinterpret_cast<const int*>(field.entries());
    const auto* masks = reinterpret_cast<const int*>(field.masks());
    const __m256i thirtyOne = _mm256_set1_epi32(31);
    const __m256i nine = _mm256_set1_epi32(9);
    const __m256 thr = _mm256_set1_ps(cx.thr);
    const std::int32_t* copyOffsets = field.maskCopyOffsets();
    const bool vectorBlend = field.copyOffsetsValid();
    alignas(32) float px[8], py[8], pz[8];
    alignas(32) std::int32_t cxs[8], cys[8], czs[8], bs[8];
    float vPrev = 0;
    std::int32_t iPrev = -1;
    for (std::int32_t i0 = 0; i0 < l.n;) {
        {
            // Blocks with no cell that can reach the threshold, from the chunk's first sample.
            const auto f0 = static_cast<float>(i0);
            const unsigned u[3] = {
                std::min(static_cast<unsigned>(static_cast<int>(l.qx + f0 * l.sx)), cx.cellMax[0]),
                std::min(static_cast<unsigned>(static_cast<int>(l.qy + f0 * l.sy)), cx.cellMax[1]),
                std::min(static_cast<unsigned>(static_cast<int>(l.qz + f0 * l.sz)), cx.cellMax[2])};
            const unsigned dBlocks = field.blockDistance((u[0] >> 3) * cx.strideX +
                                                         (u[1] >> 3) * cx.strideY + (u[2] >> 3));
            if (const std::int32_t run = latticeColdRun(l, dBlocks); run >= 8) {
                i0 += run + 1;
                continue;
            }
        }
        const __m256 fi = _mm256_cvtepi32_ps(_mm256_add_epi32(_mm256_set1_epi32(i0), lane));
        const __m256 vx = _mm256_add_ps(qx, _mm256_mul_ps(fi, sx));
        const __m256 vy = _mm256_add_ps(qy, _mm256_mul_ps(fi, sy));
        const __m256 vz = _mm256_add_ps(qz, _mm256_mul_ps(fi, sz));
        const __m256i ux = _mm256_min_epu32(_mm256_cvttps_epi32(vx), mx);
        const __m256i uy = _mm256_min_epu32(_mm256_cvttps_epi32(vy), my);
        const __m256i uz = _mm256_min_epu32(_mm256_cvttps_epi32(vz), mz);
        const __m256i b = _mm256_add_epi32(
            _mm256_add_epi32(_mm256_mullo_epi32(_mm256_srli_epi32(ux, 3), strideX),
                             _mm256_mullo_epi32(_mm256_srli_epi32(uy, 3), strideY)),
            _mm256_srli_epi32(uz, 3));
        // The samples' mask words (entry >> 5 is the mask index, 16 words each), and each
        // sample's bit moved to the sign: cell l is bit l % 32 of word l / 32.
        const __m256i e = _mm256_i32gather_epi32(entries, b, 4);
        const __m256i local =
            _mm256_or_si256(_mm256_or_si256(_mm256_slli_epi32(_mm256_and_si256(ux, seven), 6),
                                            _mm256_slli_epi32(_mm256_and_si256(uy, seven), 3)),
                            _mm256_and_si256(uz, seven));
        const __m256i word =
            _mm256_add_epi32(_mm256_slli_epi32(_mm256_srli_epi32(e, HitField::kDistanceBits), 4),
                             _mm256_srli_epi32(local, 5));
        const __m256i bits =
            _mm256_sllv_epi32(_mm256_i32gather_epi32(masks, word, 4),
                              _mm256_sub_epi32(thirtyOne, _mm256_and_si256(local, thirtyOne)));
        const std::int32_t valid = std::min(l.n - i0, 8);
        unsigned hot = static_cast<unsigned>(_mm256_movemask_ps(_mm256_castsi256_ps(bits))) &
                       ((1u << valid) - 1u);
        const std::int32_t chunk = i0;
        i0 += 8;
        if (hot == 0) continue;
        if (vectorBlend && __builtin_popcount(hot) >= kVectorBlendLanes) {
            // All eight samples blended at once (lanes in blocks with no such cell read copy 0
            // and are masked out): no branch per sample; the same float operations as lerp8().
            const __m256i copyOff = _mm256_i32gather_epi32(
                copyOffsets, _mm256_srli_epi32(e, HitField::kDistanceBits), 4);
            const __m256i o = _mm256_add_epi32(
                copyOff,
                _mm256_add_epi32(
                    _mm256_mullo_epi32(
                        _mm256_add_epi32(_mm256_mullo_epi32(_mm256_and_si256(ux, seven), nine),
                                         _mm256_and_si256(uy, seven)),
                        nine),
                    _mm256_and_si256(uz, seven)));
            const float* base = cx.tb->padded;
            const __m256 fx = _mm256_sub_ps(vx, _mm256_cvtepi32_ps(ux));
            const __m256 fy = _mm256_sub_ps(vy, _mm256_cvtepi32_ps(uy));
            const __m256 fz = _mm256_sub_ps(vz, _mm256_cvtepi32_ps(uz));
            const __m256 a00 = lerpAvx(gatherCorner(base, o, 0), gatherCorner(base, o, 81), fx);
            const __m256 a01 = lerpAvx(gatherCorner(base, o, 1), gatherCorner(base, o, 82), fx);
            const __m256 a10 = lerpAvx(gatherCorner(base, o, 9), gatherCorner(base, o, 90), fx);
            const __m256 a11 = lerpAvx(gatherCorner(base, o, 10), gatherCorner(base, o, 91), fx);
            const __m256 val = lerpAvx(lerpAvx(a00, a10, fy), lerpAvx(a01, a11, fy), fz);
            const unsigned hits =
                static_cast<unsigned>(_mm256_movemask_ps(_mm256_cmp_ps(val, thr, _CMP_GE_OQ))) &
                hot;
            alignas(32) float vals[8];
            _mm256_store_ps(vals, val);
            if (hits != 0) {
                const int k = __builtin_ctz(hits);
                const std::int32_t i = chunk + k;
                // The sample blended before it: the last hot lane before k, else the chunks'.
                if (const unsigned before = hot & ((1u << k) - 1u); before != 0) {
                    const int kp = 31 - __builtin_clz(before);
                    vPrev = vals[kp];
                    iPrev = chunk + kp;
                }
                return latticeHitAt(cx, m, l, i, iPrev == i - 1, vPrev, vals[k]);
            }
            const int kl = 31 - __builtin_clz(hot);
            vPrev = vals[kl];
            iPrev = chunk + kl;
            continue;
        }
        _mm256_store_ps(px, vx);
        _mm256_store_ps(py, vy);
        _mm256_store_ps(pz, vz);
        storeAvx(cxs, ux);
        storeAvx(cys, uy);
        storeAvx(czs, uz);
        storeAvx(bs, _mm256_srli_epi32(e, HitField::kDistanceBits));  // mask indices
        for (; hot != 0; hot &= hot - 1) {
            const int k = __builtin_ctz(hot);
            const std::int32_t i = chunk + k;
            const auto ax = static_cast<unsigned>(cxs[k]), ay = static_cast<unsigned>(cys[k]),
                       az = static_cast<unsigned>(czs[k]);
            const float* copy = field.maskCopy(static_cast<std::uint32_t>(bs[k]));
            const float v = lerp8(copy + (((ax & 7) * 9 + (ay & 7)) * 9 + (az & 7)),
                                  px[k] - static_cast<float>(ax), py[k] - static_cast<float>(ay),
                                  pz[k] - static_cast<float>(az));
            if (v >= cx.thr) return latticeHitAt(cx, m, l, i, iPrev == i - 1, vPrev, v);
            vPrev = v;
            iPrev = i;
        }
    }
    return latticeEnd(cx, m, l);
}

__attribute__((target("avx2"))) RayHit marchLatticeAvx2Call(const HitContext& cx,
                                                            HitMarch& m) noexcept {
    Lattice l;
    startLattice(m, l);
    return marchLatticeAvx2(cx, m, l);
}

/// One ray of a bundle, set up (startHit(), startLattice()) before any ray is marched.
struct LatticeRay {
    HitMarch m;
    Lattice l;
    RayHit h;
    bool ok;
};

/// Up to kMaxBundleRays LatticeRays in uninitialised storage.
struct LatticeRays {
    alignas(LatticeRay) unsigned char bytes[sizeof(LatticeRay) * kMaxBundleRays];
    LatticeRay& operator[](int i) noexcept {
        return *std::launder(reinterpret_cast<LatticeRay*>(bytes) + i);
    }
    LatticeRay& make(int i) noexcept {
        return *::new (static_cast<void*>(bytes + static_cast<std::size_t>(i) * sizeof(LatticeRay)))
            LatticeRay;
    }
};
// On the tracing thread's stack, with the Refinements: a servo thread's default stack holds both
// many times over.
static_assert(sizeof(LatticeRays) <= 32 * 1024 && sizeof(Refinements) <= 32 * 1024);

/// std::min(a, b) and std::max(a, b) in each lane, NaN and signed zeros included:
/// _mm256_min_pd(x, y) is (x < y) ? x : y, so the operands go in swapped.
PALP_AVX2_HOT __m256d minStd(__m256d a, __m256d b) noexcept { return _mm256_min_pd(b, a); }
PALP_AVX2_HOT __m256d maxStd(__m256d a, __m256d b) noexcept { return _mm256_max_pd(b, a); }

/// Bundle rays at .. at + 3 of one of its arrays, as doubles.
PALP_AVX2_HOT __m256d loadRays4(const std::array<float, kMaxBundleRays>& a,
                                std::size_t at) noexcept {
    return _mm256_cvtps_pd(_mm_loadu_ps(a.data() + at));
}

/// The vector set-up's results for a whole bundle, per ray (structure of arrays), filled four
/// rays at a time by startLatticeRays4() and copied into each LatticeRay by fillLatticeRay().
struct LatticeSetups {
    alignas(32) double o[3][kMaxBundleRays];
    alignas(32) double d[3][kMaxBundleRays];
    alignas(32) double inv[3][kMaxBundleRays];
    alignas(32) double rel[3][kMaxBundleRays];  // table-relative origin
    alignas(32) double length[kMaxBundleRays];
    alignas(32) double kLast[kMaxBundleRays];
    alignas(32) double kBegin[kMaxBundleRays];
    alignas(32) double kEnd[kMaxBundleRays];
    alignas(16) float s[3][kMaxBundleRays];  // one lattice step
    alignas(16) float q[3][kMaxBundleRays];  // the lattice's first sample
    std::uint64_t lanes = 0;                 // bit i: ray i was set up here
};
static_assert(sizeof(LatticeSetups) <= 16 * 1024);

/// startBundleRay() and startLattice() of the HitField path for bundle rays i0 .. i0 + 3, four
/// lanes of doubles at once: the same IEEE operations in the same order per lane, so every value
/// equals the scalar set-up's bit for bit (the single-ray path's, which the tests compare). A
/// ray the scalar set-up refuses (NaN or infinite input, a negative length, a zero direction) or
/// whose direction has a zero component (the clip's special case) is left to the scalar set-up.
/// Stores the results at rays i0 .. i0 + 3 of @p out and sets their bits in out.lanes (only
/// rays below @p count). Needs a usable, clipped context (as a field does), i0 a multiple of 4.
/// No branch on the data, so the chains of several groups of four overlap.
__attribute__((target("avx2"))) void startLatticeRays4(const HitContext& cx,
                                                       const RayBundle& bundle, int i0, int count,
                                                       LatticeSetups& out) noexcept {
    const auto at = static_cast<std::size_t>(i0);
    const __m256d ox = loadRays4(bundle.ox, at), oy = loadRays4(bundle.oy, at),
                  oz = loadRays4(bundle.oz, at);
    const __m256d dx = loadRays4(bundle.dx, at), dy = loadRays4(bundle.dy, at),
                  dz = loadRays4(bundle.dz, at);
    const __m256d len = loadRays4(bundle.length, at);
    const __m256d zero = _mm256_setzero_pd();
    const __m256d inf = _mm256_set1_pd(kInf);
    // Finite inputs (x * 0 == 0), a length >= 0, 0 < |d| < inf, no zero component.
    __m256d ok = _mm256_cmp_pd(len, zero, _CMP_GE_OQ);
    for (const __m256d v : {ox, oy, oz, dx, dy, dz, len})
        ok = _mm256_and_pd(ok, _mm256_cmp_pd(_mm256_mul_pd(v, zero), zero, _CMP_EQ_OQ));
    for (const __m256d v : {dx, dy, dz})
        ok = _mm256_and_pd(ok, _mm256_cmp_pd(v, zero, _CMP_NEQ_OQ));
    const __m256d n = _mm256_sqrt_pd(_mm256_add_pd(
        _mm256_add_pd(_mm256_mul_pd(dx, dx), _mm256_mul_pd(dy, dy)), _mm256_mul_pd(dz, dz)));
    ok = _mm256_and_pd(
        ok, _mm256_and_pd(_mm256_cmp_pd(n, zero, _CMP_GT_OQ), _mm256_cmp_pd(n, inf, _CMP_LT_OQ)));
    const int live = count - i0 >= 4 ? 0xF : (1 << (count - i0)) - 1;
    out.lanes |= static_cast<std::uint64_t>(_mm256_movemask_pd(ok) & live) << i0;
    // setupHitRay(): index origin, direction in index units per metre, its inverse, the samples.
    const VolumeView& view = *cx.view;
    const __m256d iv = _mm256_set1_pd(view.inverseVoxelSize());
    const __m256d o[3] = {
        _mm256_mul_pd(_mm256_sub_pd(ox, _mm256_set1_pd(view.worldOrigin().x())), iv),
        _mm256_mul_pd(_mm256_sub_pd(oy, _mm256_set1_pd(view.worldOrigin().y())), iv),
        _mm256_mul_pd(_mm256_sub_pd(oz, _mm256_set1_pd(view.worldOrigin().z())), iv)};
    const __m256d scale = _mm256_div_pd(iv, n);
    const __m256d d[3] = {_mm256_mul_pd(dx, scale), _mm256_mul_pd(dy, scale),
                          _mm256_mul_pd(dz, scale)};
    const __m256d one = _mm256_set1_pd(1.0);
    const __m256d inv[3] = {_mm256_div_pd(one, d[0]), _mm256_div_pd(one, d[1]),
                            _mm256_div_pd(one, d[2])};
    const __m256d invStep = _mm256_set1_pd(cx.invStep);
    const __m256d length = minStd(len, _mm256_set1_pd(cx.lengthCap));
    const __m256d kLast = maxStd(
        zero, _mm256_round_pd(_mm256_sub_pd(_mm256_mul_pd(length, invStep), _mm256_set1_pd(1e-9)),
                              _MM_FROUND_TO_POS_INF | _MM_FROUND_NO_EXC));
    __m256d t0 = zero, t1 = length;
    for (int a = 0; a < 3; ++a) {
        const __m256d ta = _mm256_mul_pd(_mm256_sub_pd(_mm256_set1_pd(cx.lo[a]), o[a]), inv[a]);
        const __m256d tb = _mm256_mul_pd(_mm256_sub_pd(_mm256_set1_pd(cx.hi[a]), o[a]), inv[a]);
        t0 = maxStd(t0, minStd(ta, tb));
        t1 = minStd(t1, maxStd(ta, tb));
    }
    const __m256d inside = _mm256_cmp_pd(t0, t1, _CMP_LE_OQ);
    const __m256d kBegin = _mm256_and_pd(
        inside, maxStd(zero, _mm256_round_pd(_mm256_mul_pd(t0, invStep),
                                             _MM_FROUND_TO_NEG_INF | _MM_FROUND_NO_EXC)));
    const __m256d kEnd =
        _mm256_blendv_pd(_mm256_set1_pd(-1.0),
                         minStd(kLast, _mm256_round_pd(_mm256_mul_pd(t1, invStep),
                                                       _MM_FROUND_TO_POS_INF | _MM_FROUND_NO_EXC)),
                         inside);
    // startHit(): table-relative origin, one lattice step in floats.
    const __m256d step = _mm256_set1_pd(cx.step);
    const __m256d rel[3] = {_mm256_sub_pd(o[0], _mm256_set1_pd(cx.tb->origin[0])),
                            _mm256_sub_pd(o[1], _mm256_set1_pd(cx.tb->origin[1])),
                            _mm256_sub_pd(o[2], _mm256_set1_pd(cx.tb->origin[2]))};
    const __m128 sv[3] = {_mm256_cvtpd_ps(_mm256_mul_pd(d[0], step)),
                          _mm256_cvtpd_ps(_mm256_mul_pd(d[1], step)),
                          _mm256_cvtpd_ps(_mm256_mul_pd(d[2], step))};
    // startLattice(): the first sample's exact position, rounded to float.
    const __m256d t = _mm256_mul_pd(kBegin, step);
    const __m128 qv[3] = {_mm256_cvtpd_ps(_mm256_add_pd(rel[0], _mm256_mul_pd(t, d[0]))),
                          _mm256_cvtpd_ps(_mm256_add_pd(rel[1], _mm256_mul_pd(t, d[1]))),
                          _mm256_cvtpd_ps(_mm256_add_pd(rel[2], _mm256_mul_pd(t, d[2])))};
    for (std::size_t a = 0; a < 3; ++a) {
        _mm256_store_pd(out.o[a] + at, o[a]);
        _mm256_store_pd(out.d[a] + at, d[a]);
        _mm256_store_pd(out.inv[a] + at, inv[a]);
        _mm256_store_pd(out.rel[a] + at, rel[a]);
        _mm_store_ps(out.s[a] + at, sv[a]);
        _mm_store_ps(out.q[a] + at, qv[a]);
    }
    _mm256_store_pd(out.length + at, length);
    _mm256_store_pd(out.kLast + at, kLast);
    _mm256_store_pd(out.kBegin + at, kBegin);
    _mm256_store_pd(out.kEnd + at, kEnd);
}

/// Ray @p i of @p su (set up by startLatticeRays4()) into @p ray, as startBundleRay() and
/// startLattice() would have left it.
PALP_HOT void fillLatticeRay(const HitContext& cx, const LatticeSetups& su, int i,
                             LatticeRay& ray) noexcept {
    const auto k = static_cast<std::size_t>(i);
    HitMarch& m = ray.m;
    IndexRay& r = m.r;
    for (std::size_t a = 0; a < 3; ++a) {
        r.o[a] = su.o[a][k];
        r.d[a] = su.d[a][k];
        r.inv[a] = su.inv[a][k];
    }
    r.step = cx.step;
    r.invStep = cx.invStep;
    r.length = su.length[k];
    r.kLast = static_cast<std::int64_t>(su.kLast[k]);
    r.kBegin = static_cast<std::int64_t>(su.kBegin[k]);
    r.kEnd = static_cast<std::int64_t>(su.kEnd[k]);
    m.ox = su.rel[0][k];
    m.oy = su.rel[1][k];
    m.oz = su.rel[2][k];
    m.k = r.kBegin;
    m.kRunLast = std::min(r.kEnd, r.kLast - 1);
    m.sx = su.s[0][k];
    m.sy = su.s[1][k];
    m.sz = su.s[2][k];
    m.pending = false;
    Lattice& l = ray.l;
    l.kA = r.kBegin;
    l.n = static_cast<std::int32_t>(
        std::max<std::int64_t>(0, std::min(r.kEnd, r.kLast - 1) - r.kBegin + 1));
    l.qx = su.q[0][k];
    l.qy = su.q[1][k];
    l.qz = su.q[2][k];
    l.sx = m.sx;
    l.sy = m.sy;
    l.sz = m.sz;
    const float smax = std::max({std::fabs(l.sx), std::fabs(l.sy), std::fabs(l.sz)});
    l.invSmax = smax > 0 ? 1.0f / smax : 0.0f;
    ray.ok = true;
}

/// Every ray of @p bundle set up into @p rays: the vector set-up, then the scalar one for the
/// rays it leaves.
__attribute__((target("avx2"))) void startLatticeRays(const HitContext& cx, const RayBundle& bundle,
                                                      int count, LatticeRays& rays) noexcept {
    LatticeSetups su;
    // Without a usable context (an empty view, a step that is not finite and > 0) every ray goes
    // to the scalar set-up, which refuses it.
    if (cx.usable && cx.clip)
        for (int i0 = 0; i0 < count; i0 += 4) startLatticeRays4(cx, bundle, i0, count, su);
    for (int i = 0; i < count; ++i) {
        LatticeRay& r = rays.make(i);
        if ((su.lanes >> i) & 1u) {
            fillLatticeRay(cx, su, i, r);
            continue;
        }
        r.ok = startBundleRay(cx, bundle, i, r.m, r.h);
        if (r.ok) startLattice(r.m, r.l);
    }
}

/// The bundle with a HitField on a CPU with AVX2: each ray's lattice march in one AVX2 function.
__attribute__((target("avx2"))) void traceFirstHitFieldAvx2(const HitContext& cx,
                                                            const RayBundle& bundle,
                                                            BundleHits& out) noexcept {
    prefetchPath(cx, bundle);
    // Every ray's set-up first: a chain of dependent divisions and roundings per ray that
    // overlaps across rays here, where between marches it would wait on each ray's last branch.
    // Four rays per AVX2 step (bit-identical); the rays it leaves take the scalar set-up.
    LatticeRays rays;
    startLatticeRays(cx, bundle, out.count, rays);
    Refinements refs;
    for (int i = 0; i < out.count; ++i) {
        LatticeRay& r = rays[i];
        r.m.ref = refs.next();
        const RayHit h = r.ok ? marchLatticeAvx2(cx, r.m, r.l) : r.h;
        storeHit(out, i, h);
        if (h.hit && r.m.pending) refs.commit(i);
    }
    _mm256_zeroupper();  // the refinement is SSE code
    refineAll(cx, refs, out.t.data());
}

}  // namespace

}  // namespace palp::kernels
#endif
