#pragma once
/// @file
/// Internal to the ray kernels: the volume view's sampling (cell location, corner loads,
/// trilinear blend, corner cache), the ray set-up in index units, block skipping and the
/// crossing refinement shared by the view, first-hit and accumulate.
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <limits>

#include "palp/kernels/volume_ray.h"
#include "view_table.h"

namespace palp::kernels {

// Internal to the ray kernels (not installed). Helpers are in an anonymous namespace, as they
// were in one source file: each translation unit that includes this keeps its own copies, so the
// compiler inlines them exactly as before.
namespace {  // NOLINT(google-build-namespaces)

using Table = detail::ViewTable;
constexpr double kCoordLimit = 1e9;  // index coordinates beyond this are treated as outside
constexpr double kInf = std::numeric_limits<double>::infinity();

/// A sample position resolved against the table.
struct Cell {
    std::int64_t block = -1;              // table block of the base voxel, -1 outside
    std::int64_t ix = 0, iy = 0, iz = 0;  // base voxel relative to the table origin
    float tx = 0, ty = 0, tz = 0;         // fractions in the cell
    bool finite = false;  // false: non-finite or absurd position (value: background)
};

#define PALP_HOT [[gnu::always_inline]] inline

/// floor() without a libm call (x86-64 baseline has no SSE4.1 round); |x| < 2^62.
PALP_HOT std::int64_t fastFloor(double x) noexcept {
    const auto i = static_cast<std::int64_t>(x);
    return i - (x < static_cast<double>(i) ? 1 : 0);
}

/// ceil() without a libm call; |x| < 2^62.
PALP_HOT std::int64_t fastCeil(double x) noexcept {
    const auto i = static_cast<std::int64_t>(x);
    return i + (x > static_cast<double>(i) ? 1 : 0);
}

PALP_HOT void locate(const Table& tb, double x, double y, double z, Cell& c) noexcept {
    // Written so that NaN fails the test.
    c.finite =
        std::fabs(x) < kCoordLimit && std::fabs(y) < kCoordLimit && std::fabs(z) < kCoordLimit;
    c.block = -1;
    if (!c.finite) [[unlikely]]
        return;
    const std::int64_t fx = fastFloor(x), fy = fastFloor(y), fz = fastFloor(z);
    c.ix = fx - tb.origin[0];
    c.iy = fy - tb.origin[1];
    c.iz = fz - tb.origin[2];
    c.tx = static_cast<float>(x - static_cast<double>(fx));
    c.ty = static_cast<float>(y - static_cast<double>(fy));
    c.tz = static_cast<float>(z - static_cast<double>(fz));
    const std::int64_t bx = c.ix >> 3, by = c.iy >> 3, bz = c.iz >> 3;
    // One unsigned compare per axis also rejects negative coordinates.
    if (static_cast<std::uint64_t>(bx) >= static_cast<std::uint64_t>(tb.blocks[0]) ||
        static_cast<std::uint64_t>(by) >= static_cast<std::uint64_t>(tb.blocks[1]) ||
        static_cast<std::uint64_t>(bz) >= static_cast<std::uint64_t>(tb.blocks[2])) [[unlikely]]
        return;
    c.block = (bx * tb.blocks[1] + by) * tb.blocks[2] + bz;
}

[[maybe_unused]] float voxelRel(const Table& tb, float background, std::int64_t ix, std::int64_t iy,
                                std::int64_t iz) noexcept {
    const std::int64_t bx = ix >> 3, by = iy >> 3, bz = iz >> 3;
    if (ix < 0 || iy < 0 || iz < 0 || bx >= tb.blocks[0] || by >= tb.blocks[1] ||
        bz >= tb.blocks[2])
        return background;
    const std::int64_t b = (bx * tb.blocks[1] + by) * tb.blocks[2] + bz;
    const std::int64_t off = ((ix & 7) * 9 + (iy & 7)) * 9 + (iz & 7);
    return tb.data[static_cast<std::size_t>(b)][off];
}

/// The eight corner values of cell @p c (v[4 dx + 2 dy + dz]). Inside the table they all lie in
/// the padded copy of the base voxel's block.
PALP_HOT void loadCorners(const Table& tb, float background, const Cell& c,
                          float (&v)[8]) noexcept {
    if (c.block >= 0) [[likely]] {
        const std::int64_t lx = c.ix & 7, ly = c.iy & 7, lz = c.iz & 7;
        const float* p = tb.data[static_cast<std::size_t>(c.block)] + ((lx * 9 + ly) * 9 + lz);
        v[0] = p[0];
        v[1] = p[1];
        v[2] = p[9];
        v[3] = p[10];
        v[4] = p[81];
        v[5] = p[82];
        v[6] = p[90];
        v[7] = p[91];
    } else {
        for (int i = 0; i < 8; ++i)
            v[i] = voxelRel(tb, background, c.ix + ((i >> 2) & 1), c.iy + ((i >> 1) & 1),
                            c.iz + (i & 1));
    }
}

PALP_HOT float interpolate(const Cell& c, const float (&v)[8]) noexcept {
    const float a00 = v[0] + (v[4] - v[0]) * c.tx;
    const float a01 = v[1] + (v[5] - v[1]) * c.tx;
    const float a10 = v[2] + (v[6] - v[2]) * c.tx;
    const float a11 = v[3] + (v[7] - v[3]) * c.tx;
    const float b0 = a00 + (a10 - a00) * c.ty;
    const float b1 = a01 + (a11 - a01) * c.ty;
    return b0 + (b1 - b0) * c.tz;
}

/// Trilinear value in a cell of a 9^3 padded block: @p p points at the base corner.
PALP_HOT float lerp8(const float* p, float fx, float fy, float fz) noexcept {
    const float a00 = p[0] + (p[81] - p[0]) * fx;
    const float a01 = p[1] + (p[82] - p[1]) * fx;
    const float a10 = p[9] + (p[90] - p[9]) * fx;
    const float a11 = p[10] + (p[91] - p[10]) * fx;
    const float b0 = a00 + (a10 - a00) * fy;
    const float b1 = a01 + (a11 - a01) * fy;
    return b0 + (b1 - b0) * fz;
}

PALP_HOT float sampleCell(const Table& tb, float background, const Cell& c) noexcept {
    if (!c.finite) [[unlikely]]
        return background;
    float v[8];
    loadCorners(tb, background, c, v);
    return interpolate(c, v);
}

/// The corners of the cell sampled last. At 0.5-voxel steps about half of the samples of a ray
/// (and nearly every refinement sample) fall into the cell of the sample before, so one ray
/// keeps one of these and loads corners only when the cell changes.
struct CornerCache {
    std::int64_t ix = std::numeric_limits<std::int64_t>::min(), iy = 0, iz = 0;
    /// Index position of the cached cell's base voxel (NaN: nothing cached).
    double base[3] = {std::numeric_limits<double>::quiet_NaN(), 0, 0};
    float v[8] = {0, 0, 0, 0, 0, 0, 0, 0};
};

/// The value at index position (x, y, z) when it lies in the cached cell (no locate, no load):
/// bit-identical to sampleCell() there, since the fractions are the same differences.
PALP_HOT bool sampleInCache(const CornerCache& cache, double x, double y, double z,
                            float& v) noexcept {
    const double fx = x - cache.base[0], fy = y - cache.base[1], fz = z - cache.base[2];
    if (!(fx >= 0 && fx < 1 && fy >= 0 && fy < 1 && fz >= 0 && fz < 1)) return false;  // NaN: false
    Cell c;
    c.tx = static_cast<float>(fx);
    c.ty = static_cast<float>(fy);
    c.tz = static_cast<float>(fz);
    v = interpolate(c, cache.v);
    return true;
}

/// Same value as sampleCell(), through @p cache.
PALP_HOT float sampleCached(const Table& tb, float background, const Cell& c,
                            CornerCache& cache) noexcept {
    if (!c.finite) [[unlikely]]
        return background;
    if (c.ix != cache.ix || c.iy != cache.iy || c.iz != cache.iz) {
        loadCorners(tb, background, c, cache.v);
        cache.ix = c.ix;
        cache.iy = c.iy;
        cache.iz = c.iz;
        cache.base[0] = static_cast<double>(c.ix + tb.origin[0]);
        cache.base[1] = static_cast<double>(c.iy + tb.origin[1]);
        cache.base[2] = static_cast<double>(c.iz + tb.origin[2]);
    }
    return interpolate(c, cache.v);
}

/// A ray in index space with its sample lattice.
struct IndexRay {
    double o[3] = {0, 0, 0};    // index position at t = 0
    double d[3] = {0, 0, 0};    // index units per metre
    double inv[3] = {0, 0, 0};  // metres per index unit along each axis (1 / d, inf for d = 0)
    double invStep = 0;         // 1 / step
    double length = 0;          // metres (possibly cut to kMaxSamplesPerRay)
    double step = 0;
    std::int64_t kBegin = 0, kEnd = -1;  // samples to visit (inclusive); others are background
    std::int64_t kLast = 0;              // last sample of the whole ray
    double t(std::int64_t k) const noexcept {
        return std::min(static_cast<double>(k) * step, length);
    }
};

[[maybe_unused]] bool finite3(const Eigen::Vector3d& v) noexcept {
    return std::isfinite(v.x()) && std::isfinite(v.y()) && std::isfinite(v.z());
}

/// Sets up @p r; false for degenerate input. With @p clip, samples outside the table's interior
/// (where every value is background) are left out of [kBegin, kEnd].
[[maybe_unused]] bool setupRay(const VolumeView& view, const Eigen::Vector3d& origin,
                               const Eigen::Vector3d& direction, double length, double step,
                               bool clip, IndexRay& r) noexcept {
    if (view.empty() || !finite3(origin) || !finite3(direction) || !std::isfinite(length) ||
        !(length >= 0) || !std::isfinite(step) || !(step > 0))
        return false;
    const double n = direction.norm();
    if (!(n > 0) || !std::isfinite(n)) return false;
    const Eigen::Vector3d oi = view.indexFromWorld(origin);
    const double scale = view.inverseVoxelSize() / n;
    for (int a = 0; a < 3; ++a) {
        r.o[a] = oi[a];
        r.d[a] = direction[a] * scale;
        r.inv[a] = 1.0 / r.d[a];
    }
    r.step = step;
    r.invStep = 1.0 / step;
    r.length = std::min(length, step * static_cast<double>(kMaxSamplesPerRay));
    r.kLast = fastCeil(r.length * r.invStep - 1e-9);  // <= kMaxSamplesPerRay
    if (r.kLast < 0) r.kLast = 0;
    r.kBegin = 0;
    r.kEnd = r.kLast;
    if (!clip) return true;
    // Interior of the table: base voxel and its +1 neighbours inside.
    const Table& tb = detail::viewTable(view);
    double t0 = 0, t1 = r.length;
    for (int a = 0; a < 3; ++a) {
        const double lo = tb.origin[static_cast<std::size_t>(a)];
        const double hi = lo + 8.0 * tb.blocks[static_cast<std::size_t>(a)] - 1.0;
        if (r.d[a] == 0) {
            if (r.o[a] < lo || r.o[a] >= hi) {
                r.kEnd = -1;
                return true;
            }
            continue;
        }
        double ta = (lo - r.o[a]) * r.inv[a], tbb = (hi - r.o[a]) * r.inv[a];
        if (ta > tbb) std::swap(ta, tbb);
        t0 = std::max(t0, ta);
        t1 = std::min(t1, tbb);
    }
    if (!(t0 <= t1)) {
        r.kEnd = -1;
        return true;
    }
    // 0 <= t0 <= t1 <= length here, so both quotients are at most kMaxSamplesPerRay.
    r.kBegin = std::max<std::int64_t>(0, fastFloor(t0 * r.invStep));
    r.kEnd = std::min<std::int64_t>(r.kLast, fastCeil(t1 * r.invStep));
    return true;
}

/// The value at index position (x, y, z) through @p cache.
PALP_HOT float samplePoint(const VolumeView& view, double x, double y, double z,
                           CornerCache& cache) noexcept {
    float v;
    if (sampleInCache(cache, x, y, z, v)) return v;
    Cell c;
    locate(detail::viewTable(view), x, y, z, c);
    return sampleCached(detail::viewTable(view), view.background(), c, cache);
}

PALP_HOT float sampleAt(const VolumeView& view, const IndexRay& r, double t,
                        CornerCache& cache) noexcept {
    return samplePoint(view, r.o[0] + t * r.d[0], r.o[1] + t * r.d[1], r.o[2] + t * r.d[2], cache);
}

/// Next sample index after skipping the block of @p c and every following block (a 3D DDA over
/// the block grid) for which @p skippable(maxDilated, minDilated) holds, starting at sample
/// @p k. One DDA step costs a compare and an add per axis instead of a locate, a table lookup
/// and an exit computation per block. The exit is rounded down by a hair so that rounding can
/// only revisit a sample of a skipped block (which then skips again, one sample further), never
/// jump over the first sample of the next block.
template <class Skippable>
PALP_HOT std::int64_t skipBlocks(const Table& tb, const IndexRay& r, const Cell& c, std::int64_t k,
                                 Skippable&& skippable) noexcept {
    std::int64_t b[3] = {c.ix >> 3, c.iy >> 3, c.iz >> 3};
    const std::int64_t stride[3] = {std::int64_t{tb.blocks[1]} * tb.blocks[2], tb.blocks[2], 1};
    std::int64_t dir[3];
    double tNext[3], tDelta[3];
    for (int a = 0; a < 3; ++a) {
        const auto ua = static_cast<std::size_t>(a);
        const double lo = static_cast<double>(tb.origin[ua] + 8 * b[a]);
        if (r.d[a] > 0) {
            dir[a] = 1;
            tNext[a] = (lo + 8.0 - r.o[a]) * r.inv[a];
            tDelta[a] = 8.0 * r.inv[a];
        } else if (r.d[a] < 0) {
            dir[a] = -1;
            tNext[a] = (lo - r.o[a]) * r.inv[a];
            tDelta[a] = -8.0 * r.inv[a];
        } else {
            dir[a] = 0;
            tNext[a] = kInf;
            tDelta[a] = 0;
        }
    }
    const double kEnd = static_cast<double>(r.kEnd);
    std::int64_t block = c.block;
    double tExit = 0;
    // Bounded: every step moves one block along the ray, and the ray ends within
    // kMaxSamplesPerRay samples; the table bound stops it earlier.
    for (;;) {
        const int a =
            tNext[0] <= tNext[1] ? (tNext[0] <= tNext[2] ? 0 : 2) : (tNext[1] <= tNext[2] ? 1 : 2);
        tExit = tNext[a];
        if (!(tExit * r.invStep - 1e-7 <= kEnd)) return r.kEnd + 1;  // past the last sample
        b[a] += dir[a];
        if (static_cast<std::uint64_t>(b[a]) >=
            static_cast<std::uint64_t>(tb.blocks[static_cast<std::size_t>(a)]))
            break;  // leaving the table: let the caller sample there
        block += dir[a] * stride[a];
        const auto ub = static_cast<std::size_t>(block);
        if (!skippable(tb.maxDilated[ub], tb.minDilated[ub])) break;
        tNext[a] += tDelta[a];
    }
    const double kk = tExit * r.invStep - 1e-7;
    if (!(kk <= static_cast<double>(r.kEnd))) return r.kEnd + 1;
    return std::max(k + 1, fastCeil(kk));
}

/// Regula falsi (Illinois) on v(t) - thr between ta (below) and tb (at or above).
/// fa < 0 <= fb are v - thr at ta < tb.
[[maybe_unused]] double refineCrossing(const VolumeView& view, const IndexRay& r, double thr,
                                       double ta, double fa, double tb, double fb, int iterations,
                                       CornerCache& cache) noexcept {
    double t = ta + (tb - ta) * (fa / (fa - fb));
    int side = 0;
    for (int it = 0; it < iterations; ++it) {
        const double f = static_cast<double>(sampleAt(view, r, t, cache)) - thr;
        if (!std::isfinite(f)) break;
        if (f >= 0) {
            tb = t;
            fb = f;
            if (side == 1) fa *= 0.5;
            side = 1;
        } else {
            ta = t;
            fa = f;
            if (side == -1) fb *= 0.5;
            side = -1;
        }
        if (!(fb - fa > 0)) break;
        t = ta + (tb - ta) * (fa / (fa - fb));
    }
    return std::clamp(t, ta, tb);
}

[[maybe_unused]] RayHit noHit(double length) noexcept {
    RayHit h;
    h.t = std::isfinite(length) && length > 0 ? static_cast<float>(length) : 0.0f;
    h.hit = false;
    return h;
}

}  // namespace

}  // namespace palp::kernels
