#include "palp/kernels/volume_ray.h"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <limits>
#include <new>
#include <string>
#include <type_traits>

#include "palp/base/error.h"

#if (defined(__GNUC__) || defined(__clang__)) && defined(__x86_64__)
#include <immintrin.h>
#endif

namespace palp::kernels {

namespace {

using Table = VolumeView::Table;
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

float voxelRel(const Table& tb, float background, std::int64_t ix, std::int64_t iy,
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

bool finite3(const Eigen::Vector3d& v) noexcept {
    return std::isfinite(v.x()) && std::isfinite(v.y()) && std::isfinite(v.z());
}

/// Sets up @p r; false for degenerate input. With @p clip, samples outside the table's interior
/// (where every value is background) are left out of [kBegin, kEnd].
bool setupRay(const VolumeView& view, const Eigen::Vector3d& origin,
              const Eigen::Vector3d& direction, double length, double step, bool clip,
              IndexRay& r) noexcept {
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
    const Table& tb = view.table();
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
    locate(view.table(), x, y, z, c);
    return sampleCached(view.table(), view.background(), c, cache);
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
double refineCrossing(const VolumeView& view, const IndexRay& r, double thr, double ta, double fa,
                      double tb, double fb, int iterations, CornerCache& cache) noexcept {
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

RayHit noHit(double length) noexcept {
    RayHit h;
    h.t = std::isfinite(length) && length > 0 ? static_cast<float>(length) : 0.0f;
    h.hit = false;
    return h;
}

}  // namespace

// ---------------------------------------------------------------------------------------------
// VolumeView

VolumeView::VolumeView(openvdb::FloatGrid::ConstPtr grid) : mGrid(std::move(grid)) {
    if (!mGrid) throw ValueError("volume view grid: expected a FloatGrid, found a null pointer");
    const openvdb::math::Transform& xf = mGrid->transform();
    const openvdb::Vec3d o = xf.indexToWorld(openvdb::Vec3d(0, 0, 0));
    const openvdb::Vec3d ax = xf.indexToWorld(openvdb::Vec3d(1, 0, 0)) - o;
    const openvdb::Vec3d ay = xf.indexToWorld(openvdb::Vec3d(0, 1, 0)) - o;
    const openvdb::Vec3d az = xf.indexToWorld(openvdb::Vec3d(0, 0, 1)) - o;
    const double s = ax.x();
    const double tol = 1e-9 * std::fabs(s);
    const bool ok = xf.isLinear() && s > 0 && std::isfinite(s) && std::fabs(ax.y()) <= tol &&
                    std::fabs(ax.z()) <= tol && std::fabs(ay.x()) <= tol &&
                    std::fabs(ay.z()) <= tol && std::fabs(az.x()) <= tol &&
                    std::fabs(az.y()) <= tol && std::fabs(ay.y() - s) <= tol &&
                    std::fabs(az.z() - s) <= tol;
    if (!ok)
        throw ValueError(
            "volume view transform of grid '" + mGrid->getName() +
            "': expected an isotropic axis-aligned scale and translation, found voxel axes (" +
            std::to_string(ax.x()) + ", " + std::to_string(ay.y()) + ", " + std::to_string(az.z()) +
            ") m");
    mWorldOrigin = Eigen::Vector3d(o.x(), o.y(), o.z());
    mVoxelSize = s;
    mInvVoxelSize = 1.0 / s;
    mBackground = mGrid->background();
    const openvdb::FloatTree& tree = mGrid->tree();
    openvdb::CoordBBox box;
    for (auto it = tree.cbeginLeaf(); it; ++it) box.expand(it->getNodeBoundingBox());
    {
        auto it = tree.cbeginValueAll();
        it.setMaxDepth(openvdb::FloatTree::ValueAllCIter::LEAF_DEPTH - 1);
        for (; it; ++it) {
            if (it.isTileValue() && (it.isValueOn() || *it != mBackground)) {
                openvdb::CoordBBox tb;
                it.getBoundingBox(tb);
                box.expand(tb);
            }
        }
    }
    mEmpty = box.empty();
    if (mEmpty) {
        mTable.origin = {0, 0, 0};
        mTable.blocks = {0, 0, 0};
        return;
    }
    std::array<std::int64_t, 3> n{};
    std::int64_t total = 1;
    for (openvdb::Index a = 0; a < 3; ++a) {
        const std::int64_t lo = (static_cast<std::int64_t>(box.min()[a]) >> 3) - 1;
        const std::int64_t hi = (static_cast<std::int64_t>(box.max()[a]) >> 3) + 1;
        n[a] = hi - lo + 1;
        mTable.origin[a] = static_cast<std::int32_t>(lo * 8);
        total *= n[a];
        if (total > kMaxViewBlocks) break;
    }
    if (total > kMaxViewBlocks)
        throw ValueError("volume view of grid '" + mGrid->getName() + "': expected at most " +
                         std::to_string(kMaxViewBlocks) +
                         " 8^3 blocks in the bounding box, found more");
    for (int a = 0; a < 3; ++a)
        mTable.blocks[static_cast<std::size_t>(a)] =
            static_cast<std::int32_t>(n[static_cast<std::size_t>(a)]);
    const auto count = static_cast<std::size_t>(total);
    auto index = [&](std::int64_t bx, std::int64_t by, std::int64_t bz) {
        return static_cast<std::size_t>((bx * n[1] + by) * n[2] + bz);
    };

    // Pass 1: each block's own 512 values (a leaf buffer, or a constant for tiles/background).
    std::vector<const float*> own(count, nullptr);
    std::vector<float> constant(count, mBackground);  // the value where own[b] is null
    for (std::int64_t bx = 0; bx < n[0]; ++bx)
        for (std::int64_t by = 0; by < n[1]; ++by)
            for (std::int64_t bz = 0; bz < n[2]; ++bz) {
                const openvdb::Coord c(static_cast<openvdb::Int32>(mTable.origin[0] + 8 * bx),
                                       static_cast<openvdb::Int32>(mTable.origin[1] + 8 * by),
                                       static_cast<openvdb::Int32>(mTable.origin[2] + 8 * bz));
                if (const auto* leaf = tree.probeConstLeaf(c))
                    own[index(bx, by, bz)] = leaf->buffer().data();
                else
                    constant[index(bx, by, bz)] = tree.getValue(c);
            }
    auto sameBits = [](float x, float y) { return x == y || (std::isnan(x) && std::isnan(y)); };
    // A block's padded copy is a shared constant when the block and its seven +x/+y/+z
    // neighbours (background past the table) are all the same constant.
    auto constantNeighbourhood = [&](std::int64_t bx, std::int64_t by, std::int64_t bz, float& v) {
        v = own[index(bx, by, bz)] ? 0.0f : constant[index(bx, by, bz)];
        if (own[index(bx, by, bz)]) return false;
        for (int i = 1; i < 8; ++i) {
            const std::int64_t x = bx + ((i >> 2) & 1), y = by + ((i >> 1) & 1), z = bz + (i & 1);
            if (x >= n[0] || y >= n[1] || z >= n[2]) {
                if (!sameBits(v, mBackground)) return false;
                continue;
            }
            if (own[index(x, y, z)] || !sameBits(constant[index(x, y, z)], v)) return false;
        }
        return true;
    };
    std::size_t unique = 0;
    std::vector<float> constants;  // distinct constants of constant neighbourhoods (few)
    auto constantIndex = [&](float v) -> std::size_t {
        for (std::size_t i = 0; i < constants.size(); ++i)
            if (sameBits(constants[i], v)) return i;
        constants.push_back(v);
        return constants.size() - 1;
    };
    for (std::int64_t bx = 0; bx < n[0]; ++bx)
        for (std::int64_t by = 0; by < n[1]; ++by)
            for (std::int64_t bz = 0; bz < n[2]; ++bz) {
                float v;
                if (constantNeighbourhood(bx, by, bz, v))
                    constantIndex(v);
                else
                    ++unique;
            }
    const auto padded = static_cast<std::size_t>(Table::kPadded);
    mPadded.assign((unique + constants.size()) * padded, 0.0f);
    for (std::size_t i = 0; i < constants.size(); ++i)
        std::fill_n(mPadded.data() + (unique + i) * padded, padded, constants[i]);
    mTable.padded = mPadded.data();
    mTable.paddedSize = mPadded.size();
    mTable.data.assign(count, nullptr);
    mTable.maxDilated.assign(count, mBackground);
    mTable.minDilated.assign(count, mBackground);
    auto constantBlock = [&](float v) -> const float* {
        return mPadded.data() + (unique + constantIndex(v)) * padded;
    };
    // Pass 2: the padded copies and their exact value ranges.
    std::size_t next = 0;
    for (std::int64_t bx = 0; bx < n[0]; ++bx)
        for (std::int64_t by = 0; by < n[1]; ++by)
            for (std::int64_t bz = 0; bz < n[2]; ++bz) {
                const std::size_t b = index(bx, by, bz);
                float v;
                if (constantNeighbourhood(bx, by, bz, v)) {
                    mTable.data[b] = constantBlock(v);
                    mTable.minDilated[b] = v;
                    mTable.maxDilated[b] = v;
                    continue;
                }
                float* dst = mPadded.data() + next * static_cast<std::size_t>(Table::kPadded);
                ++next;
                for (int lx = 0; lx < Table::kPad; ++lx)
                    for (int ly = 0; ly < Table::kPad; ++ly)
                        for (int lz = 0; lz < Table::kPad; ++lz) {
                            const std::int64_t x = bx + lx / 8, y = by + ly / 8, z = bz + lz / 8;
                            float value = mBackground;
                            if (x < n[0] && y < n[1] && z < n[2]) {
                                const std::size_t src = index(x, y, z);
                                value = own[src]
                                            ? own[src][((lx % 8) << 6) | ((ly % 8) << 3) | (lz % 8)]
                                            : constant[src];
                            }
                            dst[(lx * Table::kPad + ly) * Table::kPad + lz] = value;
                        }
                const auto [mn, mx] = std::minmax_element(dst, dst + Table::kPadded);
                mTable.data[b] = dst;
                mTable.minDilated[b] = *mn;
                mTable.maxDilated[b] = *mx;
            }
    // Sub-block bounds of every copy (the constant ones included, so that the index of a copy
    // is all a march needs).
    const std::size_t copies = unique + constants.size();
    mSubMax.assign(copies * Table::kSubBlocks, 0.0f);
    for (std::size_t c = 0; c < copies; ++c) {
        const float* src = mPadded.data() + c * padded;
        for (int sb = 0; sb < Table::kSubBlocks; ++sb) {
            const int x0 = 4 * ((sb >> 2) & 1), y0 = 4 * ((sb >> 1) & 1), z0 = 4 * (sb & 1);
            // NaN never reaches a threshold and never raises the bound; +-inf does.
            float mx = -std::numeric_limits<float>::infinity();
            float mn = std::numeric_limits<float>::infinity();
            for (int x = x0; x <= x0 + 4; ++x)
                for (int y = y0; y <= y0 + 4; ++y)
                    for (int z = z0; z <= z0 + 4; ++z) {
                        const float v = src[(x * Table::kPad + y) * Table::kPad + z];
                        if (v > mx) mx = v;
                        if (v < mn) mn = v;
                    }
            // A blend of values in [mn, mx] with weights in [0, 1] stays in [mn, mx] up to a few
            // ulps of mx; a run sample can sit a float rounding (well below 1e-4 voxel) outside
            // its cell, which extrapolates by that fraction of the range.
            float bound = mx + (mx - mn) * 1e-4f + std::fabs(mx) * 1e-6f;
            if (!(bound >= mx)) bound = mx;  // inf - inf, or an all-NaN sub-block
            mSubMax[c * Table::kSubBlocks + static_cast<std::size_t>(sb)] = bound;
        }
    }
    mTable.subMax = mSubMax.data();
}

float VolumeView::sampleIndex(double x, double y, double z) const noexcept {
    if (mEmpty) return mBackground;
    Cell c;
    locate(mTable, x, y, z, c);
    return sampleCell(mTable, mBackground, c);
}

}  // namespace palp::kernels

namespace palp::kernels {

// ---------------------------------------------------------------------------------------------
// TransferFunction

TransferFunction::TransferFunction(std::span<const std::array<float, 2>> nodes) {
    if (nodes.empty() || nodes.size() > static_cast<std::size_t>(kMaxNodes))
        throw ValueError("transfer function nodes: expected 1.." + std::to_string(kMaxNodes) +
                         " nodes, found " + std::to_string(nodes.size()));
    for (std::size_t i = 0; i < nodes.size(); ++i) {
        const float v = nodes[i][0], s = nodes[i][1];
        if (!std::isfinite(v) || !std::isfinite(s) || s < 0)
            throw ValueError("transfer function node " + std::to_string(i) +
                             ": expected a finite value and a finite sigma >= 0, found (" +
                             std::to_string(v) + ", " + std::to_string(s) + ")");
        if (i > 0 && v < nodes[i - 1][0])
            throw ValueError("transfer function node " + std::to_string(i) +
                             ": expected values in non-decreasing order, found " +
                             std::to_string(v) + " after " + std::to_string(nodes[i - 1][0]));
        mV[i] = v;
        mS[i] = s;
    }
    mCount = static_cast<int>(nodes.size());
    mCum[0] = 0;
    for (std::size_t i = 1; i < nodes.size(); ++i)
        mCum[i] = mCum[i - 1] + 0.5 * (static_cast<double>(mS[i - 1]) + mS[i]) *
                                    (static_cast<double>(mV[i]) - mV[i - 1]);
    mZeroBelow = std::numeric_limits<float>::infinity();
    if (mS[0] > 0) {
        mZeroBelow = -std::numeric_limits<float>::infinity();
    } else {
        for (std::size_t i = 1; i < nodes.size(); ++i)
            if (mS[i] > 0) {
                mZeroBelow = mV[i - 1];
                break;
            }
    }
}

TransferFunction TransferFunction::step(float threshold, float height) {
    const std::array<std::array<float, 2>, 2> n{{{threshold, 0.0f}, {threshold, height}}};
    return TransferFunction(n);
}

float TransferFunction::sigma(float v) const noexcept {
    if (mCount == 0) return 0;
    if (v < mV[0]) return mS[0];
    const auto last = static_cast<std::size_t>(mCount - 1);
    if (v >= mV[last]) return mS[last];
    for (std::size_t i = 0; i < last; ++i)
        if (v < mV[i + 1]) {
            const float w = mV[i + 1] - mV[i];
            return w > 0 ? mS[i] + (mS[i + 1] - mS[i]) * ((v - mV[i]) / w) : mS[i + 1];
        }
    return mS[last];
}

double TransferFunction::integral(double v) const noexcept {
    if (mCount == 0) return 0;
    if (v <= mV[0]) return mS[0] * (v - mV[0]);
    const auto last = static_cast<std::size_t>(mCount - 1);
    if (v >= mV[last]) return mCum[last] + mS[last] * (v - mV[last]);
    for (std::size_t i = 0; i < last; ++i)
        if (v < mV[i + 1]) {
            const double w = static_cast<double>(mV[i + 1]) - mV[i];
            if (!(w > 0)) continue;
            const double s = mS[i] + (static_cast<double>(mS[i + 1]) - mS[i]) * ((v - mV[i]) / w);
            return mCum[i] + 0.5 * (mS[i] + s) * (v - mV[i]);
        }
    return mCum[last];
}

// ---------------------------------------------------------------------------------------------
// Marching

void validateFirstHitParams(const FirstHitParams& p) {
    if (!(std::isfinite(p.step) && p.step > 0))
        throw ValueError("first-hit step: expected a finite step > 0 m, found " +
                         std::to_string(p.step));
    if (std::isnan(p.threshold))
        throw ValueError("first-hit threshold: expected a number, found NaN");
    if (p.refineIterations < 0 || p.refineIterations > 64)
        throw ValueError("first-hit refineIterations: expected 0..64, found " +
                         std::to_string(p.refineIterations));
}

void validateAccumulateParams(const AccumulateParams& p) {
    if (!(std::isfinite(p.step) && p.step > 0))
        throw ValueError("accumulate step: expected a finite step > 0 m, found " +
                         std::to_string(p.step));
    if (!(std::isfinite(p.tauStop) && p.tauStop > 0))
        throw ValueError("accumulate tauStop: expected a finite value > 0, found " +
                         std::to_string(p.tauStop));
    if (p.reportFirstHit && std::isnan(p.firstHitThreshold))
        throw ValueError("accumulate firstHitThreshold: expected a number, found NaN");
}

namespace {

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
          tb(&v.table()),
          thr(p.threshold),
          bg(v.background()),
          skip(p.skipEmpty),
          clip(!(v.background() >= p.threshold)),
          refine(p.refineIterations),
          step(p.step),
          limX(8.0 * v.table().blocks[0]),
          limY(8.0 * v.table().blocks[1]),
          limZ(8.0 * v.table().blocks[2]),
          nby(v.table().blocks[1]),
          nbz(v.table().blocks[2]) {
        usable = !v.empty() && std::isfinite(step) && step > 0;
        // The field path marches in table-relative float coordinates: it needs the table's
        // interior clipped (a background below the threshold), positions below 2^13 voxels
        // (float steps exact to about 5e-4 voxel; block indices then fit the 31-bit gather
        // indices, and a field's mask words do by construction).
        const auto& b = v.table().blocks;
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

#if (defined(__GNUC__) || defined(__clang__)) && defined(__x86_64__)
#define PALP_RAY_AVX2 1

/// a + (b - a) w in each lane, as in lerp8().
__attribute__((target("avx2"), always_inline)) inline __m256 lerpAvx(__m256 a, __m256 b,
                                                                     __m256 w) noexcept {
    return _mm256_add_ps(a, _mm256_mul_ps(_mm256_sub_ps(b, a), w));
}

#define PALP_AVX2_HOT __attribute__((target("avx2"), always_inline)) inline

/// Cell index (runCell()) of block-local positions.
PALP_AVX2_HOT __m256i cellsAvx(__m256 p) noexcept {
    return _mm256_min_epu32(_mm256_cvttps_epi32(p), _mm256_set1_epi32(7));
}

/// Sub-block index (subBlock()) of cells.
PALP_AVX2_HOT __m256i subsAvx(__m256i a, __m256i b, __m256i c) noexcept {
    return _mm256_or_si256(_mm256_or_si256(_mm256_slli_epi32(_mm256_srli_epi32(a, 2), 2),
                                           _mm256_slli_epi32(_mm256_srli_epi32(b, 2), 1)),
                           _mm256_srli_epi32(c, 2));
}

/// Run sample index where the ray leaves the sub-block of cells @p c along one axis, as in
/// subBlockJump().
PALP_AVX2_HOT __m256 exitAvx(__m256i c, __m256 hi, __m256 q, __m256 iv, __m256 far) noexcept {
    const __m256 side =
        _mm256_add_ps(_mm256_cvtepi32_ps(_mm256_slli_epi32(_mm256_srli_epi32(c, 2), 2)), hi);
    return _mm256_add_ps(_mm256_mul_ps(_mm256_sub_ps(side, q), iv), far);
}

PALP_AVX2_HOT __m256i loadAvx(const std::int32_t* p) noexcept {
    return _mm256_load_si256(reinterpret_cast<const __m256i*>(p));
}

PALP_AVX2_HOT void storeAvx(std::int32_t* p, __m256i v) noexcept {
    _mm256_store_si256(reinterpret_cast<__m256i*>(p), v);
}

/// A lattice step blends its samples in cells that can reach the threshold all eight at once
/// (gathers) from this many on, one by one below.
#ifndef PALP_VECTOR_BLEND_LANES
#define PALP_VECTOR_BLEND_LANES 5
#endif
constexpr int kVectorBlendLanes = PALP_VECTOR_BLEND_LANES;

/// The floats at @p base + @p o + @p c in each lane.
PALP_AVX2_HOT __m256 gatherCorner(const float* base, __m256i o, int c) noexcept {
    return _mm256_i32gather_ps(base, _mm256_add_epi32(o, _mm256_set1_epi32(c)), 4);
}

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
#endif

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
bool detectAvx2() noexcept {
    __builtin_cpu_init();
    return __builtin_cpu_supports("avx2");
}
const bool kHasAvx2 = detectAvx2();  // once, at load
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

AccumulateHit accumulate(const VolumeView& view, const Eigen::Vector3d& origin,
                         const Eigen::Vector3d& direction, double length,
                         const AccumulateParams& params) noexcept {
    AccumulateHit out;
    out.t = std::isfinite(length) && length > 0 ? static_cast<float>(length) : 0.0f;
    const TransferFunction& tf = params.sigma;
    const float thr = params.firstHitThreshold;
    const bool wantHit = params.reportFirstHit;
    const float bg = view.background();
    const bool clip = !(tf.sigma(bg) > 0) && !(wantHit && bg >= thr);
    IndexRay r;
    if (!(params.tauStop > 0) || !setupRay(view, origin, direction, length, params.step, clip, r))
        return out;
    out.t = static_cast<float>(r.length);
    const Table& tb = view.table();
    const float zeroBelow = tf.zeroBelow();
    const bool skip = params.skipEmpty;
    double tau = 0;
    float prev = 0;
    double prevT = 0;
    bool prevValid = false;
    bool found = false;
    double hitT = 0;
    Cell c;
    CornerCache cache;
    for (std::int64_t k = r.kBegin; k <= r.kEnd;) {
        const double t = r.t(k);
        locate(tb, r.o[0] + t * r.d[0], r.o[1] + t * r.d[1], r.o[2] + t * r.d[2], c);
        if (skip && c.block >= 0) {
            const float mx = tb.maxDilated[static_cast<std::size_t>(c.block)];
            if (mx < zeroBelow && (!wantHit || found || mx < thr)) {
                const bool hitDone = !wantHit || found;
                k = skipBlocks(tb, r, c, k, [zeroBelow, hitDone, thr](float bmx, float) {
                    return bmx < zeroBelow && (hitDone || bmx < thr);
                });
                prevValid = false;
                continue;
            }
        }
        const float v = sampleCached(tb, bg, c, cache);
        if (k == 0) {
            if (wantHit && v >= thr) {
                found = true;
                hitT = 0;
            }
            prev = v;
            prevT = 0;
            prevValid = true;
            ++k;
            continue;
        }
        if (!prevValid) {
            prevT = r.t(k - 1);
            prev = sampleAt(view, r, prevT, cache);
        }
        if (wantHit && !found && v >= thr) {
            found = true;
            hitT = prev >= thr
                       ? prevT
                       : refineCrossing(view, r, thr, prevT, static_cast<double>(prev) - thr, t,
                                        static_cast<double>(v) - thr, 4, cache);
        }
        const double dt = t - prevT;
        const double v0 = prev, dv = static_cast<double>(v) - v0;
        const bool flat = std::fabs(dv) <= 1e-6 * std::max(1.0, std::fabs(v0));
        const double s0 = flat ? 0.0 : tf.integral(v0);
        const double seg = flat ? dt * tf.sigma(static_cast<float>(v0 + 0.5 * dv))
                                : dt * (tf.integral(static_cast<double>(v)) - s0) / dv;
        if (tau + seg >= params.tauStop && seg > 0) {
            double u;
            if (flat) {
                u = (params.tauStop - tau) / seg;
            } else {
                double lo = 0, hi = 1;
                for (int it = 0; it < 48; ++it) {
                    const double mid = 0.5 * (lo + hi);
                    const double g = tau + dt * (tf.integral(v0 + mid * dv) - s0) / dv;
                    if (g >= params.tauStop)
                        hi = mid;
                    else
                        lo = mid;
                }
                u = hi;
            }
            const double ts = prevT + std::clamp(u, 0.0, 1.0) * dt;
            out.t = static_cast<float>(ts);
            out.integral = static_cast<float>(params.tauStop);
            out.stopped = true;
            out.firstHit = found && hitT <= ts;
            out.firstHitT = out.firstHit ? static_cast<float>(hitT) : 0.0f;
            return out;
        }
        tau += seg;
        prev = v;
        prevT = t;
        prevValid = true;
        ++k;
    }
    out.integral = static_cast<float>(tau);
    out.firstHit = found;
    out.firstHitT = found ? static_cast<float>(hitT) : 0.0f;
    return out;
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
        view.table().padded != nullptr && view.table().paddedSize < (std::size_t{1} << 31) - 128) {
        traceFirstHitAvx2(cx, bundle, out);
        return;
    }
#endif
    traceFirstHitScalar(cx, bundle, out);
}

void traceAccumulate(const VolumeView& view, const RayBundle& bundle,
                     const AccumulateParams& params, BundleAccumulation& out) noexcept {
    out.count = bundle.valid ? std::clamp(bundle.count, 0, kMaxBundleRays) : 0;
    for (int i = 0; i < out.count; ++i) {
        const auto r = static_cast<std::size_t>(i);
        const AccumulateHit h = accumulate(
            view, Eigen::Vector3d(bundle.ox[r], bundle.oy[r], bundle.oz[r]),
            Eigen::Vector3d(bundle.dx[r], bundle.dy[r], bundle.dz[r]), bundle.length[r], params);
        out.t[r] = h.t;
        out.integral[r] = h.integral;
        out.firstHitT[r] = h.firstHitT;
        out.stopped[r] = h.stopped ? 1 : 0;
        out.firstHit[r] = h.firstHit ? 1 : 0;
    }
}

}  // namespace palp::kernels
