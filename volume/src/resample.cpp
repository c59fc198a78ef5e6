#include "palp/volume/resample.h"

#include <openvdb/tools/Prune.h>
#include <tbb/blocked_range2d.h>
#include <tbb/enumerable_thread_specific.h>
#include <tbb/parallel_for.h>

#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <limits>
#include <memory>
#include <numeric>
#include <sstream>

#include "palp/base/bounds.h"
#include "palp/base/error.h"
#include "palp/base/parallel.h"
#include "palp/base/validate.h"
#include "vdb_errors.h"

namespace palp::volume {

namespace {

using LeafT = openvdb::FloatTree::LeafNodeType;
constexpr int kLeafDim = static_cast<int>(LeafT::DIM);

std::string vecStr(const Eigen::Vector3d& v) {
    std::ostringstream os;
    os << "(" << v.x() << ", " << v.y() << ", " << v.z() << ")";
    return os.str();
}

/// Geometry shared by all slices plus each slice's offset, prepared once per resample.
struct StackGeometry {
    Eigen::Vector3d normal;
    Eigen::Matrix2d gramInverse;     // inverse of [u v]^T [u v]
    Eigen::Vector3d u, v;            // column and row steps
    std::vector<std::size_t> order;  // slice indices sorted along the normal
    std::vector<double> along;       // normal coordinate of each sorted slice
};

StackGeometry analyse(const SliceStack& stack) {
    if (stack.slices.empty()) throw ValueError("resample: expected at least one slice, found none");
    checkStackValues(stack);
    StackGeometry g;
    const Slice& first = stack.slices.front();
    g.u = first.colStep;
    g.v = first.rowStep;
    for (const Slice& s : stack.slices) {
        if (s.cols <= 0 || s.rows <= 0 ||
            s.values.size() !=
                static_cast<std::size_t>(s.cols) * static_cast<std::size_t>(s.rows)) {
            throw ValueError(s.source + ": expected " + std::to_string(s.cols) + "x" +
                             std::to_string(s.rows) + " values, found " +
                             std::to_string(s.values.size()));
        }
        if (!s.position.allFinite() || !s.colStep.allFinite() || !s.rowStep.allFinite()) {
            throw ValueError(s.source + ": slice geometry is not finite");
        }
        if (s.cols != first.cols || s.rows != first.rows) {
            throw ValueError(s.source + ": expected " + std::to_string(first.cols) + "x" +
                             std::to_string(first.rows) + " pixels like " + first.source +
                             ", found " + std::to_string(s.cols) + "x" + std::to_string(s.rows));
        }
        const double tol = 1e-4 * std::max(g.u.norm(), g.v.norm());
        if ((s.colStep - g.u).norm() > tol || (s.rowStep - g.v).norm() > tol) {
            throw ValueError(s.source + ": expected the orientation and spacing of " +
                             first.source + " (steps " + vecStr(g.u) + ", " + vecStr(g.v) +
                             " m), found " + vecStr(s.colStep) + ", " + vecStr(s.rowStep));
        }
    }
    const Eigen::Vector3d cross = g.u.cross(g.v);
    if (cross.norm() < 1e-12 * g.u.norm() * g.v.norm() || g.u.norm() <= 0 || g.v.norm() <= 0) {
        throw ValueError(first.source + ": expected independent row and column directions, found " +
                         vecStr(g.u) + " and " + vecStr(g.v));
    }
    g.normal = cross.normalized();
    Eigen::Matrix2d gram;
    gram << g.u.dot(g.u), g.u.dot(g.v), g.u.dot(g.v), g.v.dot(g.v);
    g.gramInverse = gram.inverse();

    g.order.resize(stack.slices.size());
    std::iota(g.order.begin(), g.order.end(), std::size_t{0});
    std::vector<double> s(stack.slices.size());
    for (std::size_t i = 0; i < s.size(); ++i) s[i] = stack.slices[i].position.dot(g.normal);
    std::stable_sort(g.order.begin(), g.order.end(),
                     [&](std::size_t a, std::size_t b) { return s[a] < s[b]; });
    g.along.resize(s.size());
    for (std::size_t i = 0; i < s.size(); ++i) g.along[i] = s[g.order[i]];
    const double minStep = std::min(g.u.norm(), g.v.norm());
    for (std::size_t i = 1; i < g.along.size(); ++i) {
        if (g.along[i] - g.along[i - 1] < 1e-6 * minStep) {
            throw ValueError(stack.slices[g.order[i]].source +
                             ": expected distinct slice positions, found the same position as " +
                             stack.slices[g.order[i - 1]].source +
                             " (a 4D series needs a time point)");
        }
    }
    return g;
}

/// Bilinear sample of one slice at continuous (c, r), with the edge pixels extended (clamped)
/// outside the pixel centres. Returns false when (c, r) is more than (mc, mr) pixels outside.
inline bool sampleSlice(const Slice& s, double c, double r, double& out, double mc, double mr) {
    const double cmax = s.cols - 1;
    const double rmax = s.rows - 1;
    const bool inside = c >= -mc && c <= cmax + mc && r >= -mr && r <= rmax + mr;
    if (!(c == c) || !(r == r)) return false;
    c = std::clamp(c, 0.0, cmax);
    r = std::clamp(r, 0.0, rmax);
    const int c0 = std::min(static_cast<int>(c), std::max(s.cols - 2, 0));
    const int r0 = std::min(static_cast<int>(r), std::max(s.rows - 2, 0));
    const double fc = c - c0;
    const double fr = r - r0;
    const int c1 = std::min(c0 + 1, s.cols - 1);
    const int r1 = std::min(r0 + 1, s.rows - 1);
    const auto at = [&](int cc, int rr) {
        return static_cast<double>(
            s.values[static_cast<std::size_t>(rr) * static_cast<std::size_t>(s.cols) +
                     static_cast<std::size_t>(cc)]);
    };
    const double top = at(c0, r0) * (1 - fc) + at(c1, r0) * fc;
    const double bottom = at(c0, r1) * (1 - fc) + at(c1, r1) * fc;
    out = top * (1 - fr) + bottom * fr;
    return inside;
}

/// Spacing of the slices along the normal, and the gantry tilt.
struct StackSpacing {
    double minGap = 0, maxGap = 0, medianGap = 0;  // metres, 0 for a single slice
    double tiltDeg = 0;  // angle between the slice normal and the stacking direction
};

StackSpacing measureSpacing(const SliceStack& stack, const StackGeometry& g) {
    const std::size_t n = g.order.size();
    StackSpacing out;
    std::vector<double> gaps;
    for (std::size_t i = 1; i < n; ++i) gaps.push_back(g.along[i] - g.along[i - 1]);
    if (!gaps.empty()) {
        std::vector<double> sorted = gaps;
        std::sort(sorted.begin(), sorted.end());
        out.minGap = sorted.front();
        out.maxGap = sorted.back();
        out.medianGap = sorted[sorted.size() / 2];
    }
    if (n > 1) {
        const Eigen::Vector3d stackDir =
            stack.slices[g.order.back()].position - stack.slices[g.order.front()].position;
        const double c = std::clamp(std::abs(stackDir.normalized().dot(g.normal)), 0.0, 1.0);
        out.tiltDeg = std::acos(c) * 180.0 / M_PI;
        if (out.tiltDeg < 1e-3) out.tiltDeg = 0;
    }
    return out;
}

/// The requested voxel size, or the finest input spacing (in-plane steps, smallest gap).
double chooseVoxelSize(const StackGeometry& g, const StackSpacing& spacing,
                       const ResampleOptions& options) {
    double voxel = std::min(g.u.norm(), g.v.norm());
    if (spacing.minGap > 0) voxel = std::min(voxel, spacing.minGap);
    if (options.voxelSize) voxel = *options.voxelSize;
    palp::requireWithin("resample: voxel size", voxel, bounds::kSpacing, {1e3, "mm"});
    return voxel;
}

/// The output lattice: voxel (x, y, z) is centred at lo + voxel * (x, y, z).
struct Lattice {
    Eigen::Vector3d lo;
    std::array<std::int64_t, 3> dims{};
    double voxel = 0;
};

/// Bounds the pixel centres of every slice (plus one voxel of margin), crops and checks size.
Lattice planLattice(const SliceStack& stack, const StackGeometry& g, double voxel,
                    const ResampleOptions& options) {
    const std::size_t n = g.order.size();
    // World bounding box of all pixel centres.
    Eigen::Vector3d lo = Eigen::Vector3d::Constant(std::numeric_limits<double>::infinity());
    Eigen::Vector3d hi = -lo;
    for (const Slice& s : stack.slices) {
        for (int a = 0; a < 2; ++a) {
            for (int b = 0; b < 2; ++b) {
                const Eigen::Vector3d p =
                    s.position + a * (s.cols - 1) * g.u + b * (s.rows - 1) * g.v;
                lo = lo.cwiseMin(p);
                hi = hi.cwiseMax(p);
            }
        }
    }
    if (n == 1) {  // a single slice is a slab one voxel thick
        lo -= 0.5 * voxel * g.normal.cwiseAbs();
        hi += 0.5 * voxel * g.normal.cwiseAbs();
    }
    // One voxel of margin on every side, filled by extending the edge pixels, so that trilinear
    // sampling of the grid is exact up to the outermost pixel centres (a lattice cell around a
    // point on the data's edge has corners up to one voxel away along each axis). Shifting by a
    // whole voxel keeps the lattice of an axis-aligned source on its pixel centres.
    lo -= Eigen::Vector3d::Constant(voxel);
    hi += Eigen::Vector3d::Constant(voxel);
    if (options.crop) {
        lo = lo.cwiseMax(options.crop->min);
        hi = hi.cwiseMin(options.crop->max);
        if ((hi.array() < lo.array()).any()) {
            throw ValueError("resample: the crop box " + vecStr(options.crop->min) + " - " +
                             vecStr(options.crop->max) + " m does not overlap the scan (" +
                             vecStr(lo) + " - " + vecStr(hi) + ")");
        }
    }
    Lattice lat;
    lat.lo = lo;
    lat.voxel = voxel;
    std::array<std::int64_t, 3>& dims = lat.dims;
    for (int a = 0; a < 3; ++a) {
        dims[static_cast<std::size_t>(a)] =
            static_cast<std::int64_t>(std::floor((hi[a] - lo[a]) / voxel + 1e-6)) + 1;
    }
    const long double total = static_cast<long double>(dims[0]) * dims[1] * dims[2];
    if (total > static_cast<long double>(options.maxVoxels)) {
        throw ValueError("resample: a voxel size of " + std::to_string(voxel * 1e3) + " mm gives " +
                         std::to_string(dims[0]) + "x" + std::to_string(dims[1]) + "x" +
                         std::to_string(dims[2]) + " voxels, more than the limit of " +
                         std::to_string(options.maxVoxels) + "; choose a larger voxel size");
    }
    return lat;
}

/// The sorted slices prepared for sampling at world points: in-plane coordinates are affine in
/// the world point, (c, r) = M p - M position_k, and the normal coordinate is p . n.
/// Read-only after construction, so blocks may be filled from many threads.
class SliceSampler {
  public:
    SliceSampler(const SliceStack& stack, const StackGeometry& g, double voxel, float threshold)
        : mG(g), mN(g.order.size()), mThreshold(threshold) {
        const std::size_t n = mN;
        mLoAlong = g.along.front();
        mHiAlong = g.along.back();
        mAlongTol = n == 1 ? 0.5 * voxel : voxel * g.normal.lpNorm<1>() + 1e-9;
        Eigen::Matrix<double, 2, 3> uvT;
        uvT.row(0) = g.u.transpose();
        uvT.row(1) = g.v.transpose();
        mM = g.gramInverse * uvT;
        // In-plane margin in pixels: how far (in c and r) a lattice corner one voxel away can
        // reach.
        mMc = voxel * mM.row(0).lpNorm<1>() + 1e-6;
        mMr = voxel * mM.row(1).lpNorm<1>() + 1e-6;
        mInvGap.assign(n, 0.0);
        for (std::size_t k = 0; k + 1 < n; ++k) mInvGap[k] = 1.0 / (g.along[k + 1] - g.along[k]);
        mSorted.resize(n);
        mCrOffset.resize(n);
        for (std::size_t k = 0; k < n; ++k) {
            mSorted[k] = &stack.slices[g.order[k]];
            mCrOffset[k] = -(mM * mSorted[k]->position);
        }
        computeTileMaxima();
    }

    std::size_t sliceCount() const { return mN; }
    const Eigen::Matrix<double, 2, 3>& inPlaneFromWorld() const { return mM; }

    /// Whether a block with corners @p bmin, @p bmax may hold active voxels. When the whole
    /// block lies within the slices' range along the normal, sets [bracket, bracketEnd] to the
    /// slices that enclose it (else bracket = slice count).
    bool blockMayBeActive(const Eigen::Vector3d& bmin, const Eigen::Vector3d& bmax,
                          std::size_t& bracket, std::size_t& bracketEnd) const {
        const std::size_t n = mN;
        const StackGeometry& g = mG;
        bracket = n;
        double smin = std::numeric_limits<double>::infinity(), smax = -smin;
        Eigen::Vector2d crMin = Eigen::Vector2d::Constant(std::numeric_limits<double>::infinity());
        Eigen::Vector2d crMax = -crMin;
        for (int corner = 0; corner < 8; ++corner) {
            const Eigen::Vector3d p((corner & 1) ? bmax.x() : bmin.x(),
                                    (corner & 2) ? bmax.y() : bmin.y(),
                                    (corner & 4) ? bmax.z() : bmin.z());
            const double sp = p.dot(g.normal);
            smin = std::min(smin, sp);
            smax = std::max(smax, sp);
            const Eigen::Vector2d mp = mM * p;
            crMin = crMin.cwiseMin(mp);
            crMax = crMax.cwiseMax(mp);
        }
        if (smax < mLoAlong - mAlongTol || smin > mHiAlong + mAlongTol) return false;
        auto first = static_cast<std::size_t>(
            std::upper_bound(g.along.begin(), g.along.end(), smin) - g.along.begin());
        first = first > 0 ? first - 1 : 0;
        auto last = static_cast<std::size_t>(
            std::lower_bound(g.along.begin(), g.along.end(), smax) - g.along.begin());
        last = std::min(last, n - 1);
        if (n > 1 && smin >= mLoAlong && smax <= mHiAlong) {
            bracket = std::min(first, n - 2);
            bracketEnd = std::max(last, bracket + 1);
        }
        for (std::size_t k = first; k <= last; ++k) {
            if (tilesMayBeActive(k, crMin + mCrOffset[k], crMax + mCrOffset[k])) return true;
        }
        return false;
    }

    /// The value at world point @p p (slices bracketing it along the normal, each sampled
    /// bilinearly, blended by distance); false when @p p is outside the slices.
    bool valueAt(const Eigen::Vector3d& p, double& out) const {
        const std::size_t n = mN;
        const StackGeometry& g = mG;
        const double sp = p.dot(g.normal);
        if (sp < mLoAlong - mAlongTol || sp > mHiAlong + mAlongTol) return false;
        std::size_t k1 = static_cast<std::size_t>(
            std::upper_bound(g.along.begin(), g.along.end(), sp) - g.along.begin());
        std::size_t k0;
        if (k1 == 0) {
            k0 = k1 = 0;
        } else if (k1 >= n) {
            k0 = k1 = n - 1;
        } else {
            k0 = k1 - 1;
        }
        const Eigen::Vector2d mp = mM * p;
        const Eigen::Vector2d cr0 = mp + mCrOffset[k0];
        double v0 = 0;
        const bool in0 = sampleSlice(*mSorted[k0], cr0.x(), cr0.y(), v0, mMc, mMr);
        if (k0 == k1) {
            out = v0;
            return in0;
        }
        const Eigen::Vector2d cr1 = mp + mCrOffset[k1];
        double v1 = 0;
        // With tilt the slices are shifted in-plane against each other: near the edge one of
        // the two may be outside; its clamped edge value is used as long as the other is inside.
        const bool in1 = sampleSlice(*mSorted[k1], cr1.x(), cr1.y(), v1, mMc, mMr);
        if (!in0 && !in1) return false;
        const double f = (sp - g.along[k0]) / (g.along[k1] - g.along[k0]);
        out = v0 * (1 - f) + v1 * f;
        return true;
    }

    /// The value at normal coordinate @p sp and in-plane point (px, py) (without slice offset)
    /// between slices @p ka and ka + 1 (the caller has found the bracket); false when outside
    /// both slices.
    bool bracketedValue(std::size_t ka, double sp, double px, double py, double& out) const {
        double va = 0, vb = 0;
        const bool ina =
            sampleSlice(*mSorted[ka], px + mCrOffset[ka].x(), py + mCrOffset[ka].y(), va, mMc, mMr);
        const bool inb = sampleSlice(*mSorted[ka + 1], px + mCrOffset[ka + 1].x(),
                                     py + mCrOffset[ka + 1].y(), vb, mMc, mMr);
        if (!ina && !inb) return false;
        const double f = (sp - mG.along[ka]) * mInvGap[ka];
        out = va * (1 - f) + vb * f;
        return true;
    }

  private:
    static constexpr int kTile = 8;

    /// Maxima over tiles of each slice, to skip blocks whose every source pixel is background:
    /// an interpolated value is a convex combination of pixels, so it cannot exceed their
    /// maximum.
    void computeTileMaxima() {
        const std::size_t n = mN;
        mCols = mSorted.front()->cols;
        mRows = mSorted.front()->rows;
        mTilesX = (mCols + kTile - 1) / kTile;
        mTilesY = (mRows + kTile - 1) / kTile;
        const int cols = mCols, rows = mRows, tilesX = mTilesX, tilesY = mTilesY;
        mTileMax.assign(n * static_cast<std::size_t>(tilesX * tilesY),
                        -std::numeric_limits<float>::infinity());
        palp::parallelForEach(std::size_t{0}, n, [&](std::size_t k) {
            float* tm = mTileMax.data() + k * static_cast<std::size_t>(tilesX * tilesY);
            const std::vector<float>& vals = mSorted[k]->values;
            for (int r = 0; r < rows; ++r) {
                for (int c = 0; c < cols; ++c) {
                    float& m = tm[(r / kTile) * tilesX + c / kTile];
                    m = std::max(m,
                                 vals[static_cast<std::size_t>(r) * static_cast<std::size_t>(cols) +
                                      static_cast<std::size_t>(c)]);
                }
            }
        });
    }

    /// Whether any tile of slice @p k under the in-plane box [a, b] reaches the threshold.
    bool tilesMayBeActive(std::size_t k, const Eigen::Vector2d& a, const Eigen::Vector2d& b) const {
        const int cols = mCols, rows = mRows;
        if (b.x() < -mMc - 1 || a.x() > cols + mMc || b.y() < -mMr - 1 || a.y() > rows + mMr)
            return false;
        const int c0 = std::clamp(static_cast<int>(std::floor(a.x())) - 1, 0, cols - 1) / kTile;
        const int c1 = std::clamp(static_cast<int>(std::floor(b.x())) + 2, 0, cols - 1) / kTile;
        const int r0 = std::clamp(static_cast<int>(std::floor(a.y())) - 1, 0, rows - 1) / kTile;
        const int r1 = std::clamp(static_cast<int>(std::floor(b.y())) + 2, 0, rows - 1) / kTile;
        const float* tm = mTileMax.data() + k * static_cast<std::size_t>(mTilesX * mTilesY);
        for (int ty = r0; ty <= r1; ++ty)
            for (int tx = c0; tx <= c1; ++tx)
                if (tm[ty * mTilesX + tx] >= mThreshold) return true;
        return false;
    }

    const StackGeometry& mG;
    std::size_t mN;
    float mThreshold;
    double mLoAlong = 0, mHiAlong = 0, mAlongTol = 0;
    Eigen::Matrix<double, 2, 3> mM;
    double mMc = 0, mMr = 0;
    std::vector<double> mInvGap;
    std::vector<const Slice*> mSorted;
    std::vector<Eigen::Vector2d> mCrOffset;
    int mCols = 0, mRows = 0, mTilesX = 0, mTilesY = 0;
    std::vector<float> mTileMax;
};

/// What a block fill needs besides the sampler.
struct FillContext {
    const SliceSampler& sampler;
    const StackGeometry& g;
    const Lattice& lat;
    float threshold;
    float background;
};

/// Fills @p leaf for a block that lies within the slices' range, between slices [bracket,
/// bracketEnd]: the along-normal and in-plane coordinates are affine in the voxel offset.
/// Returns whether any voxel became active.
bool fillBracketedBlock(const FillContext& ctx, const openvdb::Coord& origin,
                        const Eigen::Vector3d& bmin, std::size_t bracket, std::size_t bracketEnd,
                        LeafT& leaf) {
    const StackGeometry& g = ctx.g;
    const double voxel = ctx.lat.voxel;
    const std::array<std::int64_t, 3>& dims = ctx.lat.dims;
    const Eigen::Matrix<double, 2, 3>& M = ctx.sampler.inPlaneFromWorld();
    bool any = false;
    const double s0 = bmin.dot(g.normal);
    const Eigen::Vector3d ds = voxel * g.normal;
    const Eigen::Vector2d m0 = M * bmin;
    const Eigen::Matrix<double, 2, 3> dm = voxel * M;
    const int ni = static_cast<int>(std::min<std::int64_t>(kLeafDim, dims[0] - origin.x()));
    const int nj = static_cast<int>(std::min<std::int64_t>(kLeafDim, dims[1] - origin.y()));
    const int nk = static_cast<int>(std::min<std::int64_t>(kLeafDim, dims[2] - origin.z()));
    for (int i = 0; i < ni; ++i) {
        for (int j = 0; j < nj; ++j) {
            const double sij = s0 + ds.x() * i + ds.y() * j;
            const double mx = m0.x() + dm(0, 0) * i + dm(0, 1) * j;
            const double my = m0.y() + dm(1, 0) * i + dm(1, 1) * j;
            const openvdb::Index base =
                LeafT::coordToOffset(openvdb::Coord(origin.x() + i, origin.y() + j, origin.z()));
            for (int k = 0; k < nk; ++k) {
                const double sp = sij + ds.z() * k;
                std::size_t ka = bracket;
                while (ka + 1 < bracketEnd && g.along[ka + 1] <= sp) ++ka;
                const double px = mx + dm(0, 2) * k;
                const double py = my + dm(1, 2) * k;
                double v = 0;
                if (!ctx.sampler.bracketedValue(ka, sp, px, py, v)) continue;
                const auto fv = static_cast<float>(v);
                if (fv < ctx.threshold || fv == ctx.background) continue;
                leaf.setValueOn(base + static_cast<openvdb::Index>(k), fv);
                any = true;
            }
        }
    }
    return any;
}

/// Fills @p leaf voxel by voxel (a block reaching past the first or last slice).
/// Returns whether any voxel became active.
bool fillBlock(const FillContext& ctx, const openvdb::Coord& origin, LeafT& leaf) {
    const std::array<std::int64_t, 3>& dims = ctx.lat.dims;
    bool any = false;
    for (int i = 0; i < kLeafDim; ++i) {
        const int x = origin.x() + i;
        if (x >= dims[0]) break;
        for (int j = 0; j < kLeafDim; ++j) {
            const int y = origin.y() + j;
            if (y >= dims[1]) break;
            for (int k = 0; k < kLeafDim; ++k) {
                const int z = origin.z() + k;
                if (z >= dims[2]) break;
                const Eigen::Vector3d p = ctx.lat.lo + ctx.lat.voxel * Eigen::Vector3d(x, y, z);
                double v = 0;
                if (!ctx.sampler.valueAt(p, v)) continue;
                const auto fv = static_cast<float>(v);
                if (fv < ctx.threshold || fv == ctx.background) continue;
                leaf.setValueOn(LeafT::coordToOffset(openvdb::Coord(x, y, z)), fv);
                any = true;
            }
        }
    }
    return any;
}

/// Fills @p tree block by block, one z layer of leaf blocks at a time in parallel; reports
/// progress after each layer.
/// @throw Error("resample: cancelled") when the progress callback asks to stop.
void fillTree(const FillContext& ctx, const ProgressFn& progress, openvdb::FloatTree& tree) {
    const std::size_t n = ctx.sampler.sliceCount();
    const double voxel = ctx.lat.voxel;
    const std::array<std::int64_t, 3>& dims = ctx.lat.dims;
    const int bx = static_cast<int>((dims[0] + kLeafDim - 1) / kLeafDim);
    const int by = static_cast<int>((dims[1] + kLeafDim - 1) / kLeafDim);
    const int bz = static_cast<int>((dims[2] + kLeafDim - 1) / kLeafDim);
    tbb::enumerable_thread_specific<std::vector<std::unique_ptr<LeafT>>> made;

    for (int zb = 0; zb < bz; ++zb) {
        palp::parallelFor(
            tbb::blocked_range2d<int>(0, by, 0, bx), [&](const tbb::blocked_range2d<int>& r) {
                auto& mine = made.local();
                for (int yb = r.rows().begin(); yb != r.rows().end(); ++yb) {
                    for (int xb = r.cols().begin(); xb != r.cols().end(); ++xb) {
                        const openvdb::Coord origin(xb * kLeafDim, yb * kLeafDim, zb * kLeafDim);
                        const Eigen::Vector3d bmin =
                            ctx.lat.lo +
                            voxel * Eigen::Vector3d(origin.x(), origin.y(), origin.z());
                        const Eigen::Vector3d bmax =
                            bmin + voxel * Eigen::Vector3d::Constant(kLeafDim - 1);
                        std::size_t bracket = n, bracketEnd = n;
                        if (!ctx.sampler.blockMayBeActive(bmin, bmax, bracket, bracketEnd))
                            continue;
                        auto leaf = std::make_unique<LeafT>(origin, ctx.background, false);
                        const bool any =
                            bracket < n
                                ? fillBracketedBlock(ctx, origin, bmin, bracket, bracketEnd, *leaf)
                                : fillBlock(ctx, origin, *leaf);
                        if (any) mine.push_back(std::move(leaf));
                    }
                }
            });
        for (auto& list : made) {
            for (auto& leaf : list) tree.addLeaf(leaf.release());  // the tree takes ownership
            list.clear();
        }
        if (progress && !progress(static_cast<double>(zb + 1) / bz)) {
            throw Error("resample: cancelled");
        }
    }
}

}  // namespace

void checkResampleOptions(const ResampleOptions& options) {
    if (options.voxelSize) {
        palp::requireWithin("resample: voxel size", *options.voxelSize, bounds::kSpacing,
                            {1e3, "mm"});
    }
    if (options.backgroundThreshold) {
        palp::requireWithin("resample: background threshold",
                            static_cast<double>(*options.backgroundThreshold),
                            bounds::kVolumeValue);
    }
    if (options.crop) {
        for (int a = 0; a < 3; ++a) {
            const std::string axis = "[" + std::to_string(a) + "]";
            palp::requireWithin("resample: crop min" + axis, options.crop->min[a],
                                bounds::kPosition, {1e3, "mm"});
            palp::requireWithin("resample: crop max" + axis, options.crop->max[a],
                                bounds::kPosition, {1e3, "mm"});
            if (options.crop->min[a] > options.crop->max[a]) {
                throwExpected("resample: crop" + axis, "min <= max",
                              formatValue(options.crop->min[a] * 1e3) + " > " +
                                  formatValue(options.crop->max[a] * 1e3) + " mm");
            }
        }
    }
    if (options.maxVoxels == 0) throwExpected("resample: maxVoxels", "at least 1", "0");
}

float defaultBackgroundThreshold(const VolumeInfo& info) {
    return info.modality == "CT" ? -900.0f : 0.0f;
}

float backgroundValueFor(const VolumeInfo& info, float threshold) {
    const float preferred = info.modality == "CT" ? -1000.0f : 0.0f;
    return std::min(preferred, threshold);
}

namespace {

Volume resampleChecked(const SliceStack& stack, const ResampleOptions& options) {
    const StackGeometry g = analyse(stack);
    const std::size_t n = g.order.size();
    const StackSpacing spacing = measureSpacing(stack, g);
    const double voxel = chooseVoxelSize(g, spacing, options);
    const Lattice lat = planLattice(stack, g, voxel, options);

    const float threshold =
        options.backgroundThreshold.value_or(defaultBackgroundThreshold(stack.info));
    const float background = backgroundValueFor(stack.info, threshold);

    auto grid = openvdb::FloatGrid::create(background);
    grid->setName(kScanGridName);
    auto xform = openvdb::math::Transform::createLinearTransform(voxel);
    xform->postTranslate(openvdb::Vec3d(lat.lo.x(), lat.lo.y(), lat.lo.z()));
    grid->setTransform(xform);

    const SliceSampler sampler(stack, g, voxel, threshold);
    fillTree(FillContext{sampler, g, lat, threshold, background}, options.progress, grid->tree());

    Volume out;
    out.grid = grid;
    out.info = stack.info;
    out.info.backgroundThreshold = threshold;
    out.info.minSliceGap = spacing.minGap;
    out.info.maxSliceGap = spacing.maxGap;
    out.info.originalSpacing = {g.u.norm(), g.v.norm(), spacing.medianGap};
    if (out.info.originalDims[0] == 0) {
        out.info.originalDims = {stack.slices.front().cols, stack.slices.front().rows,
                                 static_cast<std::int64_t>(n)};
    }
    // The geometry gives the angle; a DICOM Gantry/Detector Tilt (0018,1120) gives its sign,
    // which the metadata keeps as the tag says.
    out.info.gantryTiltDeg = stack.info.gantryTiltDeg < 0 ? -spacing.tiltDeg : spacing.tiltDeg;
    writeInfo(out.info, *grid);
    return out;
}

}  // namespace

Volume resample(const SliceStack& stack, const ResampleOptions& options) {
    checkResampleOptions(options);
    return detail::withVdbErrors<ValueError>("resample", "a grid OpenVDB can build",
                                             [&] { return resampleChecked(stack, options); });
}

}  // namespace palp::volume
