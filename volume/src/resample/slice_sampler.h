#pragma once
/// @file
/// Internal to palp_volume_core: the resampler's geometry (slices sorted along their normal, the
/// output lattice) and its sampler, shared by resample.cpp (planning) and resample_fill.cpp
/// (filling the grid's leaves).

#include <openvdb/tree/LeafNode.h>

#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <functional>
#include <limits>
#include <utility>
#include <vector>

#include "palp/base/parallel.h"
#include "palp/volume/resample_options.h"
#include "palp/volume/slice_stack.h"
#include "resample/leaf_sink.h"

namespace palp::volume::detail {

using LeafT = openvdb::tree::LeafNode<float, 3>;
constexpr int kLeafDim = static_cast<int>(LeafT::DIM);

/// Geometry shared by all slices plus each slice's offset, prepared once per resample.
struct StackGeometry {
    Eigen::Vector3d normal;
    Eigen::Matrix2d gramInverse;     // inverse of [u v]^T [u v]
    Eigen::Vector3d u, v;            // column and row steps
    std::vector<std::size_t> order;  // slice indices sorted along the normal
    std::vector<double> along;       // normal coordinate of each sorted slice
};

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

/// The output lattice: voxel (x, y, z) is centred at lo + step .* (x, y, z) (metres; the steps
/// along x, y, z are equal except for a native-spacing lattice).
struct Lattice {
    Eigen::Vector3d lo;
    std::array<std::int64_t, 3> dims{};
    Eigen::Vector3d step = Eigen::Vector3d::Zero();
};

/// The sorted slices prepared for sampling at world points: in-plane coordinates are affine in
/// the world point, (c, r) = M p - M position_k, and the normal coordinate is p . n.
/// Read-only after construction, so blocks may be filled from many threads.
class SliceSampler {
  public:
    /// With @p resident false the slices' values are not there yet: each sorted slice k is
    /// made usable by sliceLoaded(k) once its values are (see fillTree's window).
    /// @p step: the lattice's step along x, y, z (metres).
    SliceSampler(const SliceStack& stack, const StackGeometry& g, const Eigen::Vector3d& step,
                 float threshold, bool resident = true)
        : mG(g), mN(g.order.size()), mThreshold(threshold) {
        const std::size_t n = mN;
        mLoAlong = g.along.front();
        mHiAlong = g.along.back();
        const double alongStep = step.cwiseProduct(g.normal).lpNorm<1>();
        mAlongTol = n == 1 ? 0.5 * alongStep : alongStep + 1e-9;
        Eigen::Matrix<double, 2, 3> uvT;
        uvT.row(0) = g.u.transpose();
        uvT.row(1) = g.v.transpose();
        mM = g.gramInverse * uvT;
        // In-plane margin in pixels: how far (in c and r) a lattice corner one voxel away can
        // reach.
        mMc = mM.row(0).cwiseProduct(step.transpose()).lpNorm<1>() + 1e-6;
        mMr = mM.row(1).cwiseProduct(step.transpose()).lpNorm<1>() + 1e-6;
        mInvGap.assign(n, 0.0);
        for (std::size_t k = 0; k + 1 < n; ++k) mInvGap[k] = 1.0 / (g.along[k + 1] - g.along[k]);
        mSorted.resize(n);
        mCrOffset.resize(n);
        for (std::size_t k = 0; k < n; ++k) {
            mSorted[k] = &stack.slices[g.order[k]];
            mCrOffset[k] = -(mM * mSorted[k]->position);
        }
        mCols = mSorted.front()->cols;
        mRows = mSorted.front()->rows;
        mTilesX = (mCols + kTile - 1) / kTile;
        mTilesY = (mRows + kTile - 1) / kTile;
        mTileMax.assign(n * static_cast<std::size_t>(mTilesX * mTilesY),
                        -std::numeric_limits<float>::infinity());
        if (resident)
            palp::parallelForEach(std::size_t{0}, n, [&](std::size_t k) { sliceLoaded(k); });
    }

    /// Prepares sorted slice @p k after its values arrived (its tile maxima). Slices that are
    /// not in use may be loaded from several threads at once (each writes its own tiles).
    void sliceLoaded(std::size_t k) { computeTileMaxima(k); }

    /// The slice (in the stack's order) at sorted position @p k.
    std::size_t stackIndex(std::size_t k) const { return mG.order[k]; }

    std::size_t sliceCount() const { return mN; }
    const Eigen::Matrix<double, 2, 3>& inPlaneFromWorld() const { return mM; }
    /// Pixels of sorted slice @p k, row-major, sliceCols() x sliceRows().
    const float* sliceData(std::size_t k) const { return mSorted[k]->values.data(); }
    /// In-plane offset of sorted slice @p k: (c, r) = M p + offset.
    const Eigen::Vector2d& inPlaneOffset(std::size_t k) const { return mCrOffset[k]; }
    /// 1 / (along[k + 1] - along[k]).
    double inverseGap(std::size_t k) const { return mInvGap[k]; }
    int sliceCols() const { return mCols; }
    int sliceRows() const { return mRows; }
    /// How far outside the pixel centres (in pixels) a slice still counts as covering a point.
    double marginCols() const { return mMc; }
    double marginRows() const { return mMr; }

    /// The normal coordinates [smin, smax] the corners of the block [bmin, bmax] span.
    void blockAlong(const Eigen::Vector3d& bmin, const Eigen::Vector3d& bmax, double& smin,
                    double& smax) const {
        smin = std::numeric_limits<double>::infinity();
        smax = -smin;
        for (int corner = 0; corner < 8; ++corner) {
            const double sp = corner3(bmin, bmax, corner).dot(mG.normal);
            smin = std::min(smin, sp);
            smax = std::max(smax, sp);
        }
    }

    /// Whether normal coordinates [smin, smax] lie wholly outside the slices (no voxel there is
    /// active).
    bool outsideAlong(double smin, double smax) const {
        return smax < mLoAlong - mAlongTol || smin > mHiAlong + mAlongTol;
    }

    /// The sorted slices [first, last] whose tiles a block spanning [smin, smax] consults.
    std::pair<std::size_t, std::size_t> slicesSpanned(double smin, double smax) const {
        const std::vector<double>& along = mG.along;
        auto first = static_cast<std::size_t>(std::upper_bound(along.begin(), along.end(), smin) -
                                              along.begin());
        first = first > 0 ? first - 1 : 0;
        auto last = static_cast<std::size_t>(std::lower_bound(along.begin(), along.end(), smax) -
                                             along.begin());
        return {first, std::min(last, mN - 1)};
    }

    /// Whether a block with corners @p bmin, @p bmax may hold active voxels. Sets [bracket,
    /// bracketEnd] to the slices whose pairs its voxels blend (blendAt), or bracket = slice
    /// count for a single slice.
    bool blockMayBeActive(const Eigen::Vector3d& bmin, const Eigen::Vector3d& bmax,
                          std::size_t& bracket, std::size_t& bracketEnd) const {
        const std::size_t n = mN;
        bracket = n;
        double smin = 0, smax = 0;
        blockAlong(bmin, bmax, smin, smax);
        if (outsideAlong(smin, smax)) return false;
        Eigen::Vector2d crMin = Eigen::Vector2d::Constant(std::numeric_limits<double>::infinity());
        Eigen::Vector2d crMax = -crMin;
        for (int corner = 0; corner < 8; ++corner) {
            const Eigen::Vector2d mp = mM * corner3(bmin, bmax, corner);
            crMin = crMin.cwiseMin(mp);
            crMax = crMax.cwiseMax(mp);
        }
        const auto [first, last] = slicesSpanned(smin, smax);
        if (n > 1) {
            bracket = std::min(first, n - 2);
            bracketEnd = std::max(last, bracket + 1);
        }
        for (std::size_t k = first; k <= last; ++k) {
            if (tilesMayBeActive(k, crMin + mCrOffset[k], crMax + mCrOffset[k])) return true;
        }
        return false;
    }

    /// The slices a voxel at normal coordinate @p sp blends, as valueAt() chooses them: the
    /// pair around it, blended by @p f, or the first or last slice alone (k0 == k1, f = 0) within
    /// the tolerance beyond it. @p ka: the pair's lower slice, searched from its last value
    /// within [bracket, bracketEnd] (blockMayBeActive). False when @p sp lies outside.
    bool blendAt(double sp, std::size_t bracket, std::size_t bracketEnd, std::size_t& ka,
                 std::size_t& k0, std::size_t& k1, double& f) const {
        if (sp < mLoAlong - mAlongTol || sp > mHiAlong + mAlongTol) return false;
        if (sp < mLoAlong || sp > mHiAlong) {
            k0 = k1 = sp < mLoAlong ? 0 : mN - 1;
            f = 0;
            return true;
        }
        const std::vector<double>& along = mG.along;
        while (ka + 1 < bracketEnd && along[ka + 1] <= sp) ++ka;
        while (ka > bracket && along[ka] > sp) --ka;
        k0 = ka;
        k1 = ka + 1;
        f = (sp - along[ka]) * mInvGap[ka];
        return true;
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

  private:
    static constexpr int kTile = 8;

    static Eigen::Vector3d corner3(const Eigen::Vector3d& bmin, const Eigen::Vector3d& bmax,
                                   int corner) {
        return {(corner & 1) ? bmax.x() : bmin.x(), (corner & 2) ? bmax.y() : bmin.y(),
                (corner & 4) ? bmax.z() : bmin.z()};
    }

    /// Maxima over tiles of sorted slice @p k, to skip blocks whose every source pixel is
    /// background: an interpolated value is a convex combination of pixels, so it cannot
    /// exceed their maximum.
    void computeTileMaxima(std::size_t k) {
        const int cols = mCols, rows = mRows, tilesX = mTilesX;
        float* tm = mTileMax.data() + k * static_cast<std::size_t>(mTilesX * mTilesY);
        std::fill(tm, tm + mTilesX * mTilesY, -std::numeric_limits<float>::infinity());
        const float* vals = mSorted[k]->values.data();
        for (int r = 0; r < rows; ++r) {
            const float* row = vals + static_cast<std::ptrdiff_t>(r) * cols;
            float* tileRow = tm + (r / kTile) * tilesX;
            for (int c0 = 0; c0 < cols; c0 += kTile) {
                float m = tileRow[c0 / kTile];
                for (int c = c0; c < std::min(c0 + kTile, cols); ++c) m = std::max(m, row[c]);
                tileRow[c0 / kTile] = m;
            }
        }
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
    bool referenceOnly = false;  // every block voxel by voxel through valueAt (for tests)
    bool scalarRows = false;     // the row kernel without its AVX2 rows (for tests)
    bool perBlockRows = false;   // block by block, never whole rows of blocks (for tests)
    /// Where the filled leaves go (a grid's tree, or packed file bytes for palp convert).
    LeafSink& sink;
};

/// The lattice's steps as the row kernels use them: per voxel step along each axis, the change
/// of the normal coordinate (ds) and of the in-plane coordinates (dm), and the axis the rows run
/// along (the first along which the normal coordinate changes least).
struct LatticeSteps {
    Eigen::Vector3d ds;
    Eigen::Matrix<double, 2, 3> dm;
    int rowAxis;
};

inline LatticeSteps latticeSteps(const FillContext& ctx) {
    LatticeSteps out{ctx.lat.step.cwiseProduct(ctx.g.normal),
                     ctx.sampler.inPlaneFromWorld() * ctx.lat.step.asDiagonal(), 0};
    for (int axis = 1; axis < 3; ++axis)
        if (std::abs(out.ds[axis]) < std::abs(out.ds[out.rowAxis])) out.rowAxis = axis;
    return out;
}

/// The slices' pixel grid as the row kernels clamp it: the last column and row, the margins
/// within which a sample still counts as inside, the last pixel an interpolation starts from,
/// and the offsets to the next column and row (0 where there is a single one).
struct PixelGrid {
    int cols, rows;
    double cmax, rmax, mc, mr;
    int c0max, r0max;
    std::ptrdiff_t dc1, dr1;
};

inline PixelGrid pixelGrid(const SliceSampler& sm) {
    const int cols = sm.sliceCols(), rows = sm.sliceRows();
    return {cols,
            rows,
            static_cast<double>(cols - 1),
            static_cast<double>(rows - 1),
            sm.marginCols(),
            sm.marginRows(),
            std::max(cols - 2, 0),
            std::max(rows - 2, 0),
            cols > 1 ? 1 : 0,
            rows > 1 ? cols : 0};
}

/// Called by fillTree before each group of blocks it fills: sorted slices [lo, hi] must hold
/// their values (and SliceSampler::sliceLoaded must have run for each) when it returns; sorted
/// slices below @p releaseBelow are not used again and may be released. Called from the
/// calling thread, with @p releaseBelow and @p hi non-decreasing from call to call.
using SliceWindowFn = std::function<void(std::size_t releaseBelow, std::size_t lo, std::size_t hi)>;

/// Fills ctx.sink block by block, in groups of blocks ordered along the slice normal (each group
/// the blocks whose first slice lies in a run of kSlicesPerGroup sorted slices), each group in
/// parallel; so the slices a group reads are a bounded band, which @p window (when set) makes
/// resident before the group. Reports progress after each group.
/// @throw Error("resample: cancelled") when the progress callback asks to stop.
void fillTree(const FillContext& ctx, const ProgressFn& progress, const SliceWindowFn& window = {});

}  // namespace palp::volume::detail
