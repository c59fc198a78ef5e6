#include "palp/kernels/volume_ray.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <string>

#include "palp/error.h"

namespace palp::kernels {

namespace {

using Table = VolumeView::Table;
constexpr double kCoordLimit = 1e9;  // index coordinates beyond this are treated as outside
constexpr double kInf = std::numeric_limits<double>::infinity();

/// A sample position resolved against the table.
struct Cell {
    std::int64_t block = -1;       // table block of the base voxel, -1 outside
    std::int64_t ix = 0, iy = 0, iz = 0;  // base voxel relative to the table origin
    float tx = 0, ty = 0, tz = 0;  // fractions in the cell
    bool finite = false;           // false: non-finite or absurd position (value: background)
};

/// floor() without a libm call (x86-64 baseline has no SSE4.1 round); |x| < kCoordLimit.
inline std::int64_t fastFloor(double x) noexcept {
    const auto i = static_cast<std::int64_t>(x);
    return i - (x < static_cast<double>(i) ? 1 : 0);
}

inline void locate(const Table& tb, double x, double y, double z, Cell& c) noexcept {
    // Written so that NaN fails the test.
    c.finite = std::fabs(x) < kCoordLimit && std::fabs(y) < kCoordLimit && std::fabs(z) < kCoordLimit;
    c.block = -1;
    if (!c.finite) return;
    const std::int64_t fx = fastFloor(x), fy = fastFloor(y), fz = fastFloor(z);
    c.ix = fx - tb.origin[0];
    c.iy = fy - tb.origin[1];
    c.iz = fz - tb.origin[2];
    c.tx = static_cast<float>(x - static_cast<double>(fx));
    c.ty = static_cast<float>(y - static_cast<double>(fy));
    c.tz = static_cast<float>(z - static_cast<double>(fz));
    const std::int64_t bx = c.ix >> 3, by = c.iy >> 3, bz = c.iz >> 3;
    if (c.ix < 0 || c.iy < 0 || c.iz < 0 || bx >= tb.blocks[0] || by >= tb.blocks[1] ||
        bz >= tb.blocks[2])
        return;
    c.block = (bx * tb.blocks[1] + by) * tb.blocks[2] + bz;
}

inline float voxelRel(const Table& tb, float background, std::int64_t ix, std::int64_t iy,
                      std::int64_t iz) noexcept {
    const std::int64_t bx = ix >> 3, by = iy >> 3, bz = iz >> 3;
    if (ix < 0 || iy < 0 || iz < 0 || bx >= tb.blocks[0] || by >= tb.blocks[1] || bz >= tb.blocks[2])
        return background;
    const std::int64_t b = (bx * tb.blocks[1] + by) * tb.blocks[2] + bz;
    const std::int64_t off = ((ix & 7) << 6) | ((iy & 7) << 3) | (iz & 7);
    return tb.data[static_cast<std::size_t>(b)][off];
}

inline float sampleCell(const Table& tb, float background, const Cell& c) noexcept {
    if (!c.finite) return background;
    float v000, v001, v010, v011, v100, v101, v110, v111;
    const std::int64_t lx = c.ix & 7, ly = c.iy & 7, lz = c.iz & 7;
    if (c.block >= 0 && lx < 7 && ly < 7 && lz < 7) {
        const float* p = tb.data[static_cast<std::size_t>(c.block)] + ((lx << 6) | (ly << 3) | lz);
        v000 = p[0];
        v001 = p[1];
        v010 = p[8];
        v011 = p[9];
        v100 = p[64];
        v101 = p[65];
        v110 = p[72];
        v111 = p[73];
    } else {
        v000 = voxelRel(tb, background, c.ix, c.iy, c.iz);
        v001 = voxelRel(tb, background, c.ix, c.iy, c.iz + 1);
        v010 = voxelRel(tb, background, c.ix, c.iy + 1, c.iz);
        v011 = voxelRel(tb, background, c.ix, c.iy + 1, c.iz + 1);
        v100 = voxelRel(tb, background, c.ix + 1, c.iy, c.iz);
        v101 = voxelRel(tb, background, c.ix + 1, c.iy, c.iz + 1);
        v110 = voxelRel(tb, background, c.ix + 1, c.iy + 1, c.iz);
        v111 = voxelRel(tb, background, c.ix + 1, c.iy + 1, c.iz + 1);
    }
    const float a00 = v000 + (v100 - v000) * c.tx;
    const float a01 = v001 + (v101 - v001) * c.tx;
    const float a10 = v010 + (v110 - v010) * c.tx;
    const float a11 = v011 + (v111 - v011) * c.tx;
    const float b0 = a00 + (a10 - a00) * c.ty;
    const float b1 = a01 + (a11 - a01) * c.ty;
    return b0 + (b1 - b0) * c.tz;
}

/// A ray in index space with its sample lattice.
struct IndexRay {
    double o[3] = {0, 0, 0};  // index position at t = 0
    double d[3] = {0, 0, 0};  // index units per metre
    double length = 0;        // metres (possibly cut to kMaxSamplesPerRay)
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
bool setupRay(const VolumeView& view, const Eigen::Vector3d& origin, const Eigen::Vector3d& direction,
              double length, double step, bool clip, IndexRay& r) noexcept {
    if (view.empty() || !finite3(origin) || !finite3(direction) || !std::isfinite(length) ||
        !(length >= 0) || !std::isfinite(step) || !(step > 0))
        return false;
    const double n = direction.norm();
    if (!(n > 0) || !std::isfinite(n)) return false;
    const Eigen::Vector3d oi = view.indexFromWorld(origin);
    const double inv = 1.0 / view.voxelSize();
    for (int a = 0; a < 3; ++a) {
        r.o[a] = oi[a];
        r.d[a] = direction[a] / n * inv;
    }
    r.step = step;
    r.length = std::min(length, step * static_cast<double>(kMaxSamplesPerRay));
    r.kLast = static_cast<std::int64_t>(std::ceil(r.length / step - 1e-9));
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
        double ta = (lo - r.o[a]) / r.d[a], tbb = (hi - r.o[a]) / r.d[a];
        if (ta > tbb) std::swap(ta, tbb);
        t0 = std::max(t0, ta);
        t1 = std::min(t1, tbb);
    }
    if (!(t0 <= t1)) {
        r.kEnd = -1;
        return true;
    }
    r.kBegin = std::max<std::int64_t>(0, static_cast<std::int64_t>(std::floor(t0 / step)));
    r.kEnd = std::min<std::int64_t>(r.kLast, static_cast<std::int64_t>(std::ceil(t1 / step)));
    return true;
}

inline float sampleAt(const VolumeView& view, const IndexRay& r, double t, Cell& c) noexcept {
    locate(view.table(), r.o[0] + t * r.d[0], r.o[1] + t * r.d[1], r.o[2] + t * r.d[2], c);
    return sampleCell(view.table(), view.background(), c);
}

/// t (metres) where the ray leaves the block that holds cell @p c.
inline double blockExit(const Table& tb, const IndexRay& r, const Cell& c) noexcept {
    const std::int64_t rel[3] = {c.ix, c.iy, c.iz};
    double tExit = kInf;
    for (int a = 0; a < 3; ++a) {
        const double lo = static_cast<double>(tb.origin[static_cast<std::size_t>(a)] + (rel[a] & ~std::int64_t{7}));
        if (r.d[a] > 0)
            tExit = std::min(tExit, (lo + 8.0 - r.o[a]) / r.d[a]);
        else if (r.d[a] < 0)
            tExit = std::min(tExit, (lo - r.o[a]) / r.d[a]);
    }
    return tExit;
}

/// Next sample index after skipping the block of @p c from sample @p k.
inline std::int64_t skipBlock(const Table& tb, const IndexRay& r, const Cell& c, std::int64_t k) noexcept {
    const double tExit = blockExit(tb, r, c);
    const double kk = std::ceil(tExit / r.step);
    if (!(kk < static_cast<double>(r.kEnd + 1))) return r.kEnd + 1;
    return std::max(k + 1, static_cast<std::int64_t>(kk));
}

/// Regula falsi (Illinois) on v(t) - thr between ta (below) and tb (at or above).
/// fa < 0 <= fb are v - thr at ta < tb.
double refineCrossing(const VolumeView& view, const IndexRay& r, double thr, double ta, double fa,
                      double tb, double fb, int iterations) noexcept {
    double t = ta + (tb - ta) * (fa / (fa - fb));
    int side = 0;
    Cell c;
    for (int it = 0; it < iterations; ++it) {
        const double f = static_cast<double>(sampleAt(view, r, t, c)) - thr;
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
                    std::fabs(ax.z()) <= tol && std::fabs(ay.x()) <= tol && std::fabs(ay.z()) <= tol &&
                    std::fabs(az.x()) <= tol && std::fabs(az.y()) <= tol &&
                    std::fabs(ay.y() - s) <= tol && std::fabs(az.z() - s) <= tol;
    if (!ok)
        throw ValueError("volume view transform of grid '" + mGrid->getName() +
                         "': expected an isotropic axis-aligned scale and translation, found voxel axes (" +
                         std::to_string(ax.x()) + ", " + std::to_string(ay.y()) + ", " +
                         std::to_string(az.z()) + ") m");
    mWorldOrigin = Eigen::Vector3d(o.x(), o.y(), o.z());
    mVoxelSize = s;
    mInvVoxelSize = 1.0 / s;
    mBackground = mGrid->background();

    auto constantBlock = [this](float v) -> const float* {
        for (const auto& b : mConstantBlocks)
            if ((*b)[0] == v || (std::isnan(v) && std::isnan((*b)[0]))) return b->data();
        mConstantBlocks.push_back(std::make_unique<std::array<float, 512>>());
        mConstantBlocks.back()->fill(v);
        return mConstantBlocks.back()->data();
    };
    mBackgroundBlock = constantBlock(mBackground);

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
                         std::to_string(kMaxViewBlocks) + " 8^3 blocks in the bounding box, found more");
    for (int a = 0; a < 3; ++a)
        mTable.blocks[static_cast<std::size_t>(a)] = static_cast<std::int32_t>(n[static_cast<std::size_t>(a)]);
    const auto count = static_cast<std::size_t>(total);
    mTable.data.assign(count, mBackgroundBlock);
    std::vector<float> ownMin(count, mBackground), ownMax(count, mBackground);
    for (std::int64_t bx = 0; bx < n[0]; ++bx)
        for (std::int64_t by = 0; by < n[1]; ++by)
            for (std::int64_t bz = 0; bz < n[2]; ++bz) {
                const auto b = static_cast<std::size_t>((bx * n[1] + by) * n[2] + bz);
                const openvdb::Coord c(static_cast<openvdb::Int32>(mTable.origin[0] + 8 * bx),
                                       static_cast<openvdb::Int32>(mTable.origin[1] + 8 * by),
                                       static_cast<openvdb::Int32>(mTable.origin[2] + 8 * bz));
                if (const auto* leaf = tree.probeConstLeaf(c)) {
                    const float* d = leaf->buffer().data();
                    mTable.data[b] = d;
                    const auto [mn, mx] = std::minmax_element(d, d + 512);
                    ownMin[b] = *mn;
                    ownMax[b] = *mx;
                } else {
                    const float v = tree.getValue(c);
                    mTable.data[b] = constantBlock(v);
                    ownMin[b] = v;
                    ownMax[b] = v;
                }
            }
    mTable.maxDilated.assign(count, mBackground);
    mTable.minDilated.assign(count, mBackground);
    for (std::int64_t bx = 0; bx < n[0]; ++bx)
        for (std::int64_t by = 0; by < n[1]; ++by)
            for (std::int64_t bz = 0; bz < n[2]; ++bz) {
                float mn = std::numeric_limits<float>::infinity(), mx = -mn;
                for (int dx = 0; dx <= 1; ++dx)
                    for (int dy = 0; dy <= 1; ++dy)
                        for (int dz = 0; dz <= 1; ++dz) {
                            const std::int64_t x = bx + dx, y = by + dy, z = bz + dz;
                            float lo = mBackground, hi = mBackground;
                            if (x < n[0] && y < n[1] && z < n[2]) {
                                const auto b = static_cast<std::size_t>((x * n[1] + y) * n[2] + z);
                                lo = ownMin[b];
                                hi = ownMax[b];
                            }
                            mn = std::min(mn, lo);
                            mx = std::max(mx, hi);
                        }
                const auto b = static_cast<std::size_t>((bx * n[1] + by) * n[2] + bz);
                mTable.minDilated[b] = mn;
                mTable.maxDilated[b] = mx;
            }
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
                             ": expected values in non-decreasing order, found " + std::to_string(v) +
                             " after " + std::to_string(nodes[i - 1][0]));
        mV[i] = v;
        mS[i] = s;
    }
    mCount = static_cast<int>(nodes.size());
    mCum[0] = 0;
    for (std::size_t i = 1; i < nodes.size(); ++i)
        mCum[i] = mCum[i - 1] + 0.5 * (static_cast<double>(mS[i - 1]) + mS[i]) * (static_cast<double>(mV[i]) - mV[i - 1]);
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
        throw ValueError("first-hit step: expected a finite step > 0 m, found " + std::to_string(p.step));
    if (std::isnan(p.threshold))
        throw ValueError("first-hit threshold: expected a number, found NaN");
    if (p.refineIterations < 0 || p.refineIterations > 64)
        throw ValueError("first-hit refineIterations: expected 0..64, found " +
                         std::to_string(p.refineIterations));
}

void validateAccumulateParams(const AccumulateParams& p) {
    if (!(std::isfinite(p.step) && p.step > 0))
        throw ValueError("accumulate step: expected a finite step > 0 m, found " + std::to_string(p.step));
    if (!(std::isfinite(p.tauStop) && p.tauStop > 0))
        throw ValueError("accumulate tauStop: expected a finite value > 0, found " + std::to_string(p.tauStop));
    if (p.reportFirstHit && std::isnan(p.firstHitThreshold))
        throw ValueError("accumulate firstHitThreshold: expected a number, found NaN");
}

RayHit firstHit(const VolumeView& view, const Eigen::Vector3d& origin, const Eigen::Vector3d& direction,
                double length, const FirstHitParams& params) noexcept {
    const float thr = params.threshold;
    const bool clip = !(view.background() >= thr);
    IndexRay r;
    if (!setupRay(view, origin, direction, length, params.step, clip, r)) return noHit(length);
    const Table& tb = view.table();
    const float bg = view.background();
    const bool skip = params.skipEmpty;
    float prev = 0;
    bool prevValid = false;
    Cell c;
    for (std::int64_t k = r.kBegin; k <= r.kEnd;) {
        const double t = r.t(k);
        locate(tb, r.o[0] + t * r.d[0], r.o[1] + t * r.d[1], r.o[2] + t * r.d[2], c);
        if (skip && c.block >= 0 && tb.maxDilated[static_cast<std::size_t>(c.block)] < thr) {
            k = skipBlock(tb, r, c, k);
            prevValid = false;
            continue;
        }
        const float v = sampleCell(tb, bg, c);
        if (v >= thr) {
            if (k == 0) return {0.0f, true};
            const double tp = r.t(k - 1);
            if (!prevValid) {
                Cell cp;
                prev = sampleAt(view, r, tp, cp);
            }
            const double th = refineCrossing(view, r, thr, tp, static_cast<double>(prev) - thr, t,
                                             static_cast<double>(v) - thr, params.refineIterations);
            return {static_cast<float>(th), true};
        }
        prev = v;
        prevValid = true;
        ++k;
    }
    return noHit(r.length);
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
    for (std::int64_t k = r.kBegin; k <= r.kEnd;) {
        const double t = r.t(k);
        locate(tb, r.o[0] + t * r.d[0], r.o[1] + t * r.d[1], r.o[2] + t * r.d[2], c);
        if (skip && c.block >= 0) {
            const float mx = tb.maxDilated[static_cast<std::size_t>(c.block)];
            if (mx < zeroBelow && (!wantHit || found || mx < thr)) {
                k = skipBlock(tb, r, c, k);
                prevValid = false;
                continue;
            }
        }
        const float v = sampleCell(tb, bg, c);
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
            Cell cp;
            prev = sampleAt(view, r, prevT, cp);
        }
        if (wantHit && !found && v >= thr) {
            found = true;
            hitT = prev >= thr ? prevT
                               : refineCrossing(view, r, thr, prevT, static_cast<double>(prev) - thr, t,
                                                static_cast<double>(v) - thr, 4);
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
    for (int i = 0; i < out.count; ++i) {
        const auto r = static_cast<std::size_t>(i);
        const RayHit h = firstHit(view, Eigen::Vector3d(bundle.ox[r], bundle.oy[r], bundle.oz[r]),
                                  Eigen::Vector3d(bundle.dx[r], bundle.dy[r], bundle.dz[r]),
                                  bundle.length[r], params);
        out.t[r] = h.t;
        out.hit[r] = h.hit ? 1 : 0;
        out.geomId[r] = 0;
    }
}

void traceAccumulate(const VolumeView& view, const RayBundle& bundle, const AccumulateParams& params,
                     BundleAccumulation& out) noexcept {
    out.count = bundle.valid ? std::clamp(bundle.count, 0, kMaxBundleRays) : 0;
    for (int i = 0; i < out.count; ++i) {
        const auto r = static_cast<std::size_t>(i);
        const AccumulateHit h =
            accumulate(view, Eigen::Vector3d(bundle.ox[r], bundle.oy[r], bundle.oz[r]),
                       Eigen::Vector3d(bundle.dx[r], bundle.dy[r], bundle.dz[r]), bundle.length[r], params);
        out.t[r] = h.t;
        out.integral[r] = h.integral;
        out.firstHitT[r] = h.firstHitT;
        out.stopped[r] = h.stopped ? 1 : 0;
        out.firstHit[r] = h.firstHit ? 1 : 0;
    }
}

}  // namespace palp::kernels
