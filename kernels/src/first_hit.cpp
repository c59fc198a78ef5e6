#include <algorithm>
#include <cmath>
#include <cstring>
#include <limits>
#include <new>
#include <string>
#include <type_traits>

#include "palp/base/bounds.h"
#include "palp/base/error.h"
#include "palp/base/simd.h"
#include "palp/base/validate.h"
#include "palp/kernels/volume_ray.h"
#if (defined(__GNUC__) || defined(__clang__)) && defined(__x86_64__)
#include <immintrin.h>
#endif

#include "block_avx2.h"
#include "lattice_avx2.h"
#include "lattice_march.h"
#include "lattice_setup_check.h"

namespace palp::kernels {

// ---------------------------------------------------------------------------------------------
// Marching

void validateFirstHitParams(const FirstHitParams& p) {
    requireWithin("first-hit step", p.step, bounds::kSpacing);
    requireWithin("first-hit threshold", p.threshold, bounds::kVolumeValue);
    if (p.refineIterations < 0 || p.refineIterations > 64)
        throw ValueError("first-hit refineIterations: expected 0..64, found " +
                         std::to_string(p.refineIterations));
}

namespace {

void traceFirstHitScalar(const HitContext& cx, const RayBundle& bundle, BundleHits& out) noexcept {
    prefetchPath(cx, bundle);
    HitMarch m;  // startHit() and advanceHit() set every field a ray reads
    Refinements refs;
    for (int i = 0; i < out.count; ++i) {
        RayHit h;
        m.ref = refs.next();
        if (startBundleRay(cx, bundle, i, m, h)) {
            if (cx.field != nullptr)
                h = marchLatticeScalar(cx, m);
            else
                while (advanceHit(cx, m, h) && !runScalar(cx, m, h)) {
                }
        }
        storeHit(out, i, h);
        if (h.hit && m.pending) refs.commit(i);
    }
    refineAll(cx, refs, out.t.data());
}

}  // namespace

namespace detail {

#ifdef PALP_RAY_AVX2
namespace {
/// The bits of a value, for bit-for-bit comparison of doubles and floats (NaN included).
template <class T>
bool sameBits(const T& a, const T& b) noexcept {
    return std::memcmp(&a, &b, sizeof(T)) == 0;
}

/// Whether two set-ups of one ray hold the same bits in every field the field path reads.
bool sameLatticeSetup(const LatticeRay& a, const LatticeRay& b) noexcept {
    const IndexRay &ra = a.m.r, &rb = b.m.r;
    bool same = a.ok == b.ok && ra.kBegin == rb.kBegin && ra.kEnd == rb.kEnd &&
                ra.kLast == rb.kLast && sameBits(ra.invStep, rb.invStep) &&
                sameBits(ra.length, rb.length) && sameBits(ra.step, rb.step);
    for (int i = 0; i < 3; ++i)
        same = same && sameBits(ra.o[i], rb.o[i]) && sameBits(ra.d[i], rb.d[i]) &&
               sameBits(ra.inv[i], rb.inv[i]);
    const HitMarch &ma = a.m, &mb = b.m;
    same = same && sameBits(ma.ox, mb.ox) && sameBits(ma.oy, mb.oy) && sameBits(ma.oz, mb.oz) &&
           ma.k == mb.k && ma.kRunLast == mb.kRunLast && sameBits(ma.sx, mb.sx) &&
           sameBits(ma.sy, mb.sy) && sameBits(ma.sz, mb.sz) && ma.pending == mb.pending;
    const Lattice &la = a.l, &lb = b.l;
    return same && la.kA == lb.kA && la.n == lb.n && sameBits(la.qx, lb.qx) &&
           sameBits(la.qy, lb.qy) && sameBits(la.qz, lb.qz) && sameBits(la.sx, lb.sx) &&
           sameBits(la.sy, lb.sy) && sameBits(la.sz, lb.sz) && sameBits(la.invSmax, lb.invSmax);
}
}  // namespace
#endif

LatticeSetupCheck checkLatticeSetup(const VolumeView& view, const RayBundle& bundle,
                                    const FirstHitParams& params) noexcept {
    LatticeSetupCheck c;
#ifdef PALP_RAY_AVX2
    const HitContext cx(view, params);
    if (!bundleSimdAvailable() || cx.field == nullptr || !cx.usable || !cx.clip || !bundle.valid)
        return c;
    c.available = true;
    LatticeSetups su;
    for (int i0 = 0; i0 < bundle.count; i0 += 4)
        startLatticeRays4(cx, bundle, i0, bundle.count, su);
    LatticeRays vector, scalar;
    for (int i = 0; i < bundle.count; ++i) {
        if (((su.lanes >> i) & 1u) == 0) continue;
        ++c.vectorRays;
        fillLatticeRay(cx, su, i, vector.make(i));
        LatticeRay& r = scalar.make(i);
        r.ok = startBundleRay(cx, bundle, i, r.m, r.h);
        if (r.ok) startLattice(r.m, r.l);
        if (!sameLatticeSetup(vector[i], r)) ++c.mismatches;
    }
#else
    (void)view;
    (void)bundle;
    (void)params;
#endif
    return c;
}

}  // namespace detail

#ifdef PALP_RAY_AVX2
namespace {
const bool kHasAvx2 = palp::avx2Enabled();  // once, at load (PALP_SIMD=off: never)
}  // namespace
#endif

bool bundleSimdAvailable() noexcept {
#ifdef PALP_RAY_AVX2
    return kHasAvx2;
#else
    return false;
#endif
}

RayHit firstHit(const VolumeView& view, const Eigen::Vector3d& origin,
                const Eigen::Vector3d& direction, double length,
                const FirstHitParams& params) noexcept {
    const HitContext cx(view, params);
    HitMarch m;
    Refinements refs;
    m.ref = refs.next();
    RayHit h;
    if (startHit(cx, origin, direction, length, m, h)) {
        if (cx.field != nullptr) {
#ifdef PALP_RAY_AVX2
            h = cx.simd ? marchLatticeAvx2Call(cx, m) : marchLatticeScalar(cx, m);
#else
            h = marchLatticeScalar(cx, m);
#endif
        } else {
            while (advanceHit(cx, m, h) && !runScalar(cx, m, h)) {
            }
        }
    }
    if (h.hit && m.pending) {
        refs.commit(0);
        refineAll(cx, refs, &h.t);
    }
    return h;
}

void traceFirstHit(const VolumeView& view, const RayBundle& bundle, const FirstHitParams& params,
                   BundleHits& out) noexcept {
    out.count = bundle.valid ? std::clamp(bundle.count, 0, kMaxBundleRays) : 0;
    const HitContext cx(view, params);
#ifdef PALP_RAY_AVX2
    // HitContext admits a field only where 32-bit gather indices reach every block.
    if (cx.field != nullptr && cx.simd) {
        traceFirstHitFieldAvx2(cx, bundle, out);
        return;
    }
    // 32-bit gather offsets must reach every block copy.
    if (params.simd && kHasAvx2 && cx.field == nullptr && out.count > 1 &&
        detail::viewTable(view).padded != nullptr &&
        detail::viewTable(view).paddedSize < (std::size_t{1} << 31) - 128) {
        traceFirstHitAvx2(cx, bundle, out);
        return;
    }
#endif
    traceFirstHitScalar(cx, bundle, out);
}

}  // namespace palp::kernels
