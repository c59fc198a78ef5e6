#pragma once
/// @file
/// Internal to first-hit (first_hit.cpp): the per-call context, the per-ray set-up and march
/// state, and the refinement of a bundle's hits after the march.
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <type_traits>

#include "ray_sample.h"

namespace palp::kernels {

// Internal to the ray kernels (not installed). Helpers are in an anonymous namespace, as they
// were in one source file: each translation unit that includes this keeps its own copies, so the
// compiler inlines them exactly as before.
namespace {  // NOLINT(google-build-namespaces)

/// Everything a first-hit march reads that is the same for every ray of a call.
struct HitContext {
    const VolumeView* view = nullptr;
    const Table* tb = nullptr;
    float thr = 0;
    float bg = 0;
    bool skip = true;
    bool clip = true;
    int refine = 0;
    double step = 0;
    double limX = 0, limY = 0, limZ = 0;  // table extent, index units
    std::int64_t nby = 0, nbz = 0;
    // Per-call parts of the ray set-up.
    bool usable = false;              // a non-empty view and a finite step > 0
    const HitField* field = nullptr;  // per-cell bits at this threshold, when skipping
    bool simd = false;                // take the AVX2 run loops (params.simd and the CPU has it)
    unsigned cellMax[3] = {0, 0, 0};  // largest table-relative cell per axis (8 blocks - 1)
    std::size_t strideX = 0, strideY = 0;  // table block index = bx strideX + by strideY + bz
    double invStep = 0, lengthCap = 0;
    double lo[3] = {0, 0, 0}, hi[3] = {0, 0, 0};  // the table's interior, index units

    HitContext(const VolumeView& v, const FirstHitParams& p) noexcept
        : view(&v),
          tb(&detail::viewTable(v)),
          thr(p.threshold),
          bg(v.background()),
          skip(p.skipEmpty),
          clip(!(v.background() >= p.threshold)),
          refine(p.refineIterations),
          step(p.step),
          limX(8.0 * detail::viewTable(v).blocks[0]),
          limY(8.0 * detail::viewTable(v).blocks[1]),
          limZ(8.0 * detail::viewTable(v).blocks[2]),
          nby(detail::viewTable(v).blocks[1]),
          nbz(detail::viewTable(v).blocks[2]) {
        usable = !v.empty() && std::isfinite(step) && step > 0;
        // The field path marches in table-relative float coordinates: it needs the table's
        // interior clipped (a background below the threshold), positions below 2^13 voxels
        // (float steps exact to about 5e-4 voxel; block indices then fit the 31-bit gather
        // indices, and a field's mask words do by construction).
        const auto& b = detail::viewTable(v).blocks;
        if (p.field != nullptr && p.skipEmpty && p.field->matches(v, p.threshold) && clip &&
            std::max({b[0], b[1], b[2]}) <= 1024)
            field = p.field;
        simd = p.simd && bundleSimdAvailable();
        for (std::size_t a = 0; a < 3; ++a)
            cellMax[a] = static_cast<unsigned>(std::max(0, 8 * b[a] - 1));
        strideX = static_cast<std::size_t>(b[1]) * static_cast<std::size_t>(b[2]);
        strideY = static_cast<std::size_t>(b[2]);
        invStep = 1.0 / step;
        lengthCap = step * static_cast<double>(kMaxSamplesPerRay);
        for (std::size_t a = 0; a < 3; ++a) {
            lo[a] = tb->origin[a];
            hi[a] = lo[a] + 8.0 * tb->blocks[a] - 1.0;
        }
    }
};

/// setupRay() for first-hit with the per-call parts taken from @p cx: the same ray (up to the
/// rounding of the norm), about half the instructions.
PALP_HOT bool setupHitRay(const HitContext& cx, const Eigen::Vector3d& origin,
                          const Eigen::Vector3d& direction, double length, IndexRay& r) noexcept {
    const double dx = direction.x(), dy = direction.y(), dz = direction.z();
    // x * 0 is 0 exactly for finite x (NaN for inf and NaN): one test for all seven inputs.
    const double zero = (origin.x() * 0 + origin.y() * 0) + (origin.z() * 0 + dx * 0) +
                        (dy * 0 + dz * 0) + length * 0;
    if (!cx.usable || !(zero == 0) || !(length >= 0)) return false;
    const double n = std::sqrt(dx * dx + dy * dy + dz * dz);
    if (!(n > 0) || !(n < kInf)) return false;
    const Eigen::Vector3d oi = cx.view->indexFromWorld(origin);
    const double scale = cx.view->inverseVoxelSize() / n;
    r.o[0] = oi.x();
    r.o[1] = oi.y();
    r.o[2] = oi.z();
    r.d[0] = dx * scale;
    r.d[1] = dy * scale;
    r.d[2] = dz * scale;
    r.inv[0] = 1.0 / r.d[0];
    r.inv[1] = 1.0 / r.d[1];
    r.inv[2] = 1.0 / r.d[2];
    r.step = cx.step;
    r.invStep = cx.invStep;
    r.length = std::min(length, cx.lengthCap);
    r.kLast = std::max<std::int64_t>(0, fastCeil(r.length * r.invStep - 1e-9));
    r.kBegin = 0;
    r.kEnd = r.kLast;
    if (!cx.clip) return true;
    double t0 = 0, t1 = r.length;
    for (int a = 0; a < 3; ++a) {
        if (r.d[a] == 0) {
            if (r.o[a] < cx.lo[a] || r.o[a] >= cx.hi[a]) t1 = -1;
            continue;
        }
        const double ta = (cx.lo[a] - r.o[a]) * r.inv[a], tb = (cx.hi[a] - r.o[a]) * r.inv[a];
        t0 = std::max(t0, std::min(ta, tb));
        t1 = std::min(t1, std::max(ta, tb));
    }
    if (!(t0 <= t1)) {
        r.kEnd = -1;
        return true;
    }
    r.kBegin = std::max<std::int64_t>(0, fastFloor(t0 * r.invStep));
    r.kEnd = std::min<std::int64_t>(r.kLast, fastCeil(t1 * r.invStep));
    return true;
}

/// A first-hit refinement, recorded where the march finds the two samples that bracket the
/// crossing and carried out afterwards by refineAll(): each refinement is a chain of dependent
/// probes (position, blend, division), so a bundle refines all its hits together and the CPU
/// overlaps the chains of different rays instead of waiting on one at a time. The arithmetic of
/// one refinement does not depend on the others, so results are the same for a single ray.
/// Regula falsi (Illinois) on v - threshold over [a, b], as refineCrossing().
struct Refinement {
    // Local: the two samples lie in one run, and x is a fractional run-sample index whose probe
    // is blended from the run's block copy at the float position q + x s (runPos() at
    // integers); t = (k0 + x) step. Lattice (the HitField path): the same with q and s
    // table-relative, each probe finding its block (latticeValue()). General: x is t in
    // metres, probed on the view (double).
    bool local;
    bool lattice;
    bool needPrev;  // general: fa is still to be sampled at a
    bool done;
    int ray;
    const float* base;
    float qx, qy, qz, sx, sy, sz;
    double k0, step;
    double o[3], d[3];  // general: index-space ray
    double a, b, fa, fb, x;
    int side;
    CornerCache cache;  // general
};
static_assert(std::is_trivially_copyable_v<Refinement> &&
              std::is_trivially_destructible_v<Refinement>);

/// Up to kMaxBundleRays refinements in uninitialised storage (a bundle trace pays only for the
/// hits it has).
struct Refinements {
    alignas(Refinement) unsigned char bytes[sizeof(Refinement) * kMaxBundleRays];
    int n = 0;
    Refinement& operator[](int i) noexcept {
        return *std::launder(reinterpret_cast<Refinement*>(bytes) + i);
    }
    /// Where the next refinement is recorded (HitMarch::ref), in place.
    Refinement* next() noexcept {
        return ::new (static_cast<void*>(bytes + static_cast<std::size_t>(n) * sizeof(Refinement)))
            Refinement;
    }
    /// Keeps the refinement recorded at next() for ray @p ray.
    void commit(int ray) noexcept { (*this)[n++].ray = ray; }
};

/// One ray's first-hit march, resumable at the runs of float-placed samples through a block
/// (so that a bundle can take those runs eight rays at a time).
struct HitMarch {
    IndexRay r;
    double ox = 0, oy = 0, oz = 0;  // table-relative origin
    std::int64_t k = 0;             // next sample to visit
    std::int64_t kRunLast = 0;      // samples before kLast lie exactly at k * step
    float sx = 0, sy = 0, sz = 0;   // one lattice step in index units
    // For the sub-block jumps, per axis: 1 / s (0 where s = 0, else clamped to +-1e30), the
    // side of a sub-block the ray leaves by (4 when s > 0, else 0), and 1e30 where s = 0 (the
    // ray never leaves along that axis).
    float ivx = 0, ivy = 0, ivz = 0;
    float hix = 0, hiy = 0, hiz = 0;
    float farx = 0, fary = 0, farz = 0;
    // A block's exit along each axis, (face - l) * invF + far: the block-local face the ray
    // leaves by (8 or 0), 1 / d (0 where d = 0), and +inf where d = 0 (never left).
    double face[3] = {0, 0, 0}, invF[3] = {0, 0, 0}, far[3] = {0, 0, 0};
    // The pending run (after advanceHit() returned true): samples runK + i, i = 1 .. runN - 1,
    // at block-local positions q + float(i) s (each one rounded the same way wherever it is
    // computed) in block copy `base`; `prev` is sample runK (taken on its exact position).
    // Bit s of `occ` is set when the copy's sub-block s may hold a value >= the threshold.
    const float* base = nullptr;
    float qx = 0, qy = 0, qz = 0, prev = 0;
    unsigned occ = 0xFFu;
    // A hit's refinement, still to run (refineAll()); false for a hit at t = 0 or no hit.
    bool pending = false;
    Refinement* ref = nullptr;  // where a hit records its refinement (Refinements::next())
    std::int64_t runK = 0, runN = 0;
};

/// Block-local position of run sample @p i (i >= 1), one axis: the same float operations in the
/// scalar and AVX2 runs, so a sample's value does not depend on which samples were taken before.
PALP_HOT float runPos(float q, float s, std::int64_t i) noexcept {
    return q + static_cast<float>(i) * s;
}

/// Cell index (clamped into the 9^3 copy) of a block-local float coordinate: truncation; -0.x (a
/// hair before the entry) gives cell 0, and the unsigned min keeps every index inside the copy.
PALP_HOT unsigned runCell(float p) noexcept {
    return std::min(static_cast<unsigned>(static_cast<int>(p)), 7u);
}

/// Sets up @p m; false (and @p out set) when the ray is degenerate or empty.
PALP_HOT bool startHit(const HitContext& cx, const Eigen::Vector3d& origin,
                       const Eigen::Vector3d& direction, double length, HitMarch& m,
                       RayHit& out) noexcept {
    if (!setupHitRay(cx, origin, direction, length, m.r)) {
        out = noHit(length);
        return false;
    }
    const Table& tb = *cx.tb;
    m.ox = m.r.o[0] - tb.origin[0];
    m.oy = m.r.o[1] - tb.origin[1];
    m.oz = m.r.o[2] - tb.origin[2];
    m.k = m.r.kBegin;
    m.kRunLast = std::min(m.r.kEnd, m.r.kLast - 1);
    m.sx = static_cast<float>(m.r.d[0] * m.r.step);
    m.sy = static_cast<float>(m.r.d[1] * m.r.step);
    m.sz = static_cast<float>(m.r.d[2] * m.r.step);
    m.pending = false;
    if (cx.field != nullptr) return true;  // the lattice march needs no more
    // 1 / s from 1 / d (no division; the jumps check where they land, so the estimate need not
    // be exact).
    auto axis = [&](float sa, double inv, float& iv, float& hi, float& far) {
        iv = sa == 0 ? 0.0f : static_cast<float>(std::clamp(inv * m.r.invStep, -1e30, 1e30));
        hi = sa > 0 ? 4.0f : 0.0f;
        far = sa == 0 ? 1e30f : 0.0f;
    };
    axis(m.sx, m.r.inv[0], m.ivx, m.hix, m.farx);
    axis(m.sy, m.r.inv[1], m.ivy, m.hiy, m.fary);
    axis(m.sz, m.r.inv[2], m.ivz, m.hiz, m.farz);
    for (int a = 0; a < 3; ++a) {
        m.face[a] = m.r.d[a] > 0 ? 8.0 : 0.0;
        m.invF[a] = m.r.d[a] != 0 ? m.r.inv[a] : 0.0;
        m.far[a] = m.r.d[a] != 0 ? 0.0 : kInf;
    }
    return true;
}

/// Records a refinement between float-placed samples i - 1 and i (values @p vPrev, @p v) at
/// positions q + u s with t = (k0 + u) step: of a block run (@p lattice false; probes blended
/// from copy @p base) or of the HitField path's lattice (probes find their block).
PALP_HOT void recordFloatRefinement(const HitContext& cx, HitMarch& m, bool lattice,
                                    const float* base, float qx, float qy, float qz, double k0,
                                    double i, float vPrev, float v) noexcept {
    Refinement& f = *m.ref;
    f.local = !lattice;
    f.lattice = lattice;
    f.needPrev = false;
    f.done = false;
    f.base = base;
    f.qx = qx;
    f.qy = qy;
    f.qz = qz;
    f.sx = m.sx;
    f.sy = m.sy;
    f.sz = m.sz;
    f.k0 = k0;
    f.step = m.r.step;
    f.a = i - 1;
    f.b = i;
    f.fa = static_cast<double>(vPrev) - static_cast<double>(cx.thr);
    f.fb = static_cast<double>(v) - static_cast<double>(cx.thr);
    f.side = 0;
    m.pending = true;
}

/// Records the refinement of a crossing between run samples j - 1 and j (both in the pending
/// run of @p m, j > runK) from their values: every probe lies in the run's block. Returns the
/// provisional hit (t of sample j), refined by refineAll(). Run samples lie before the ray's
/// last (cut) sample, so t_k = k step there.
PALP_HOT RayHit refineHit(const HitContext& cx, HitMarch& m, std::int64_t j, float vPrev,
                          float v) noexcept {
    recordFloatRefinement(cx, m, false, m.base, m.qx, m.qy, m.qz, static_cast<double>(m.runK),
                          static_cast<double>(j - m.runK), vPrev, v);
    return {static_cast<float>(m.r.t(j)), true};
}

/// A hit at sample j whose predecessor has not been sampled: the first sample of every run reads
/// its predecessor on the exact (double) position instead of taking a march value, so a result
/// does not depend on whether the blocks before were skipped. Records a general refinement
/// that samples the predecessor first.
PALP_HOT RayHit hitAtSample(const HitContext& cx, HitMarch& m, std::int64_t j, float v) noexcept {
    if (j == 0) return {0.0f, true};
    Refinement& f = *m.ref;
    f.local = false;
    f.lattice = false;
    f.needPrev = true;
    f.done = false;
    for (int a = 0; a < 3; ++a) {
        f.o[a] = m.r.o[a];
        f.d[a] = m.r.d[a];
    }
    f.a = m.r.t(j - 1);
    f.b = m.r.t(j);
    f.fa = 0;
    f.fb = static_cast<double>(v) - static_cast<double>(cx.thr);
    f.side = 0;
    f.cache = CornerCache{};
    m.pending = true;
    return {static_cast<float>(f.b), true};
}

/// Trilinear value at the table-relative float position (px, py, pz) of a lattice sample (the
/// HitField path; positions lie in the table's interior up to rounding): the cell by
/// truncation, clamped to the table, its block's padded copy from the table.
PALP_HOT float latticeValue(const HitContext& cx, float px, float py, float pz) noexcept {
    const Table& tb = *cx.tb;
    const unsigned ux = std::min(static_cast<unsigned>(static_cast<int>(px)), cx.cellMax[0]);
    const unsigned uy = std::min(static_cast<unsigned>(static_cast<int>(py)), cx.cellMax[1]);
    const unsigned uz = std::min(static_cast<unsigned>(static_cast<int>(pz)), cx.cellMax[2]);
    const std::size_t b = (ux >> 3) * cx.strideX + (uy >> 3) * cx.strideY + (uz >> 3);
    return lerp8(tb.data[b] + (((ux & 7) * 9 + (uy & 7)) * 9 + (uz & 7)),
                 px - static_cast<float>(ux), py - static_cast<float>(uy),
                 pz - static_cast<float>(uz));
}

/// The value @p f's refinement probes at x (the caller subtracts the threshold).
PALP_HOT float probe(const HitContext& cx, Refinement& f, double x) noexcept {
    if (f.lattice) {
        const auto u = static_cast<float>(x);
        return latticeValue(cx, f.qx + u * f.sx, f.qy + u * f.sy, f.qz + u * f.sz);
    }
    if (!f.local)
        return samplePoint(*cx.view, f.o[0] + x * f.d[0], f.o[1] + x * f.d[1], f.o[2] + x * f.d[2],
                           f.cache);
    const auto u = static_cast<float>(x);
    const float px = f.qx + u * f.sx, py = f.qy + u * f.sy, pz = f.qz + u * f.sz;
    const unsigned cx0 = runCell(px), cy0 = runCell(py), cz0 = runCell(pz);
    return lerp8(f.base + ((cx0 * 9 + cy0) * 9 + cz0), px - static_cast<float>(cx0),
                 py - static_cast<float>(cy0), pz - static_cast<float>(cz0));
}

/// Runs refinements @p fs[0 .. n), each params.refineIterations regula-falsi steps, step by step
/// across all of them, and stores each refined t in @p t[ray].
void refineAll(const HitContext& cx, Refinements& fs, float* t) noexcept {
    const auto thr = static_cast<double>(cx.thr);
    for (int i = 0; i < fs.n; ++i) {
        Refinement& f = fs[i];
        if (f.needPrev) f.fa = static_cast<double>(probe(cx, f, f.a)) - thr;
        f.x = f.a + (f.b - f.a) * (f.fa / (f.fa - f.fb));
    }
    for (int it = 0; it < cx.refine; ++it)
        for (int i = 0; i < fs.n; ++i) {
            Refinement& f = fs[i];
            if (f.done) continue;
            const double v = static_cast<double>(probe(cx, f, f.x)) - thr;
            if (!std::isfinite(v)) {
                f.done = true;
                continue;
            }
            if (v >= 0) {
                f.b = f.x;
                f.fb = v;
                if (f.side == 1) f.fa *= 0.5;
                f.side = 1;
            } else {
                f.a = f.x;
                f.fa = v;
                if (f.side == -1) f.fb *= 0.5;
                f.side = -1;
            }
            if (!(f.fb - f.fa > 0)) {
                f.done = true;
                continue;
            }
            f.x = f.a + (f.b - f.a) * (f.fa / (f.fa - f.fb));
        }
    for (int i = 0; i < fs.n; ++i) {
        const Refinement& f = fs[i];
        const double x = std::clamp(f.x, f.a, f.b);
        t[f.ray] = static_cast<float>(f.local || f.lattice ? (f.k0 + x) * f.step : x);
    }
}

}  // namespace

}  // namespace palp::kernels
