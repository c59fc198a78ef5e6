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

#include "palp/base/error.h"
#include "palp/base/parallel.h"

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

}  // namespace

float defaultBackgroundThreshold(const VolumeInfo& info) {
    return info.modality == "CT" ? -900.0f : 0.0f;
}

float backgroundValueFor(const VolumeInfo& info, float threshold) {
    const float preferred = info.modality == "CT" ? -1000.0f : 0.0f;
    return std::min(preferred, threshold);
}

Volume resample(const SliceStack& stack, const ResampleOptions& options) {
    const StackGeometry g = analyse(stack);
    const std::size_t n = g.order.size();

    // Gaps along the normal, tilt and default voxel size.
    std::vector<double> gaps;
    for (std::size_t i = 1; i < n; ++i) gaps.push_back(g.along[i] - g.along[i - 1]);
    double minGap = 0, maxGap = 0, medianGap = 0;
    if (!gaps.empty()) {
        std::vector<double> sorted = gaps;
        std::sort(sorted.begin(), sorted.end());
        minGap = sorted.front();
        maxGap = sorted.back();
        medianGap = sorted[sorted.size() / 2];
    }
    double tiltDeg = 0;
    if (n > 1) {
        const Eigen::Vector3d stackDir =
            stack.slices[g.order.back()].position - stack.slices[g.order.front()].position;
        const double c = std::clamp(std::abs(stackDir.normalized().dot(g.normal)), 0.0, 1.0);
        tiltDeg = std::acos(c) * 180.0 / M_PI;
        if (tiltDeg < 1e-3) tiltDeg = 0;
    }
    double voxel = std::min(g.u.norm(), g.v.norm());
    if (minGap > 0) voxel = std::min(voxel, minGap);
    if (options.voxelSize) voxel = *options.voxelSize;
    if (!(voxel > 0) || !std::isfinite(voxel)) {
        throw ValueError("resample: expected a positive voxel size, found " +
                         std::to_string(voxel) + " m");
    }

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
    std::array<std::int64_t, 3> dims{};
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

    const float threshold =
        options.backgroundThreshold.value_or(defaultBackgroundThreshold(stack.info));
    const float background = backgroundValueFor(stack.info, threshold);

    auto grid = openvdb::FloatGrid::create(background);
    grid->setName(kScanGridName);
    auto xform = openvdb::math::Transform::createLinearTransform(voxel);
    xform->postTranslate(openvdb::Vec3d(lo.x(), lo.y(), lo.z()));
    grid->setTransform(xform);

    const double loAlong = g.along.front();
    const double hiAlong = g.along.back();
    const double alongTol = n == 1 ? 0.5 * voxel : voxel * g.normal.lpNorm<1>() + 1e-9;

    // In-plane coordinates are affine in the world point: (c, r) = M p - M position_k.
    Eigen::Matrix<double, 2, 3> uvT;
    uvT.row(0) = g.u.transpose();
    uvT.row(1) = g.v.transpose();
    const Eigen::Matrix<double, 2, 3> M = g.gramInverse * uvT;
    // In-plane margin in pixels: how far (in c and r) a lattice corner one voxel away can reach.
    const double mc = voxel * M.row(0).lpNorm<1>() + 1e-6;
    const double mr = voxel * M.row(1).lpNorm<1>() + 1e-6;
    std::vector<double> invGap(n, 0.0);
    for (std::size_t k = 0; k + 1 < n; ++k) invGap[k] = 1.0 / (g.along[k + 1] - g.along[k]);
    std::vector<const Slice*> sorted(n);
    std::vector<Eigen::Vector2d> crOffset(n);
    for (std::size_t k = 0; k < n; ++k) {
        sorted[k] = &stack.slices[g.order[k]];
        crOffset[k] = -(M * sorted[k]->position);
    }

    // Maxima over tiles of each slice, to skip blocks whose every source pixel is background:
    // an interpolated value is a convex combination of pixels, so it cannot exceed their maximum.
    constexpr int kTile = 8;
    const int cols = sorted.front()->cols;
    const int rows = sorted.front()->rows;
    const int tilesX = (cols + kTile - 1) / kTile;
    const int tilesY = (rows + kTile - 1) / kTile;
    std::vector<float> tileMax(n * static_cast<std::size_t>(tilesX * tilesY),
                               -std::numeric_limits<float>::infinity());
    palp::parallelForEach(std::size_t{0}, n, [&](std::size_t k) {
        float* tm = tileMax.data() + k * static_cast<std::size_t>(tilesX * tilesY);
        const std::vector<float>& vals = sorted[k]->values;
        for (int r = 0; r < rows; ++r) {
            for (int c = 0; c < cols; ++c) {
                float& m = tm[(r / kTile) * tilesX + c / kTile];
                m = std::max(m, vals[static_cast<std::size_t>(r) * static_cast<std::size_t>(cols) +
                                     static_cast<std::size_t>(c)]);
            }
        }
    });

    // Returns whether a block may hold active voxels. When the whole block lies within the
    // slices' range along the normal, sets [bracket, bracketEnd] to the slices that enclose it
    // (else bracket = n).
    auto blockMayBeActive = [&](const Eigen::Vector3d& bmin, const Eigen::Vector3d& bmax,
                                std::size_t& bracket, std::size_t& bracketEnd) -> bool {
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
            const Eigen::Vector2d mp = M * p;
            crMin = crMin.cwiseMin(mp);
            crMax = crMax.cwiseMax(mp);
        }
        if (smax < loAlong - alongTol || smin > hiAlong + alongTol) return false;
        auto first = static_cast<std::size_t>(
            std::upper_bound(g.along.begin(), g.along.end(), smin) - g.along.begin());
        first = first > 0 ? first - 1 : 0;
        auto last = static_cast<std::size_t>(
            std::lower_bound(g.along.begin(), g.along.end(), smax) - g.along.begin());
        last = std::min(last, n - 1);
        if (n > 1 && smin >= loAlong && smax <= hiAlong) {
            bracket = std::min(first, n - 2);
            bracketEnd = std::max(last, bracket + 1);
        }
        for (std::size_t k = first; k <= last; ++k) {
            const Eigen::Vector2d a = crMin + crOffset[k];
            const Eigen::Vector2d b = crMax + crOffset[k];
            if (b.x() < -mc - 1 || a.x() > cols + mc || b.y() < -mr - 1 || a.y() > rows + mr)
                continue;
            const int c0 = std::clamp(static_cast<int>(std::floor(a.x())) - 1, 0, cols - 1) / kTile;
            const int c1 = std::clamp(static_cast<int>(std::floor(b.x())) + 2, 0, cols - 1) / kTile;
            const int r0 = std::clamp(static_cast<int>(std::floor(a.y())) - 1, 0, rows - 1) / kTile;
            const int r1 = std::clamp(static_cast<int>(std::floor(b.y())) + 2, 0, rows - 1) / kTile;
            const float* tm = tileMax.data() + k * static_cast<std::size_t>(tilesX * tilesY);
            for (int ty = r0; ty <= r1; ++ty)
                for (int tx = c0; tx <= c1; ++tx)
                    if (tm[ty * tilesX + tx] >= threshold) return true;
        }
        return false;
    };

    auto valueAt = [&](const Eigen::Vector3d& p, double& out) -> bool {
        const double sp = p.dot(g.normal);
        if (sp < loAlong - alongTol || sp > hiAlong + alongTol) return false;
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
        const Eigen::Vector2d mp = M * p;
        const Eigen::Vector2d cr0 = mp + crOffset[k0];
        double v0 = 0;
        const bool in0 = sampleSlice(*sorted[k0], cr0.x(), cr0.y(), v0, mc, mr);
        if (k0 == k1) {
            out = v0;
            return in0;
        }
        const Eigen::Vector2d cr1 = mp + crOffset[k1];
        double v1 = 0;
        // With tilt the slices are shifted in-plane against each other: near the edge one of
        // the two may be outside; its clamped edge value is used as long as the other is inside.
        const bool in1 = sampleSlice(*sorted[k1], cr1.x(), cr1.y(), v1, mc, mr);
        if (!in0 && !in1) return false;
        const double f = (sp - g.along[k0]) / (g.along[k1] - g.along[k0]);
        out = v0 * (1 - f) + v1 * f;
        return true;
    };

    const int bx = static_cast<int>((dims[0] + kLeafDim - 1) / kLeafDim);
    const int by = static_cast<int>((dims[1] + kLeafDim - 1) / kLeafDim);
    const int bz = static_cast<int>((dims[2] + kLeafDim - 1) / kLeafDim);
    openvdb::FloatTree& tree = grid->tree();
    tbb::enumerable_thread_specific<std::vector<std::unique_ptr<LeafT>>> made;

    for (int zb = 0; zb < bz; ++zb) {
        palp::parallelFor(
            tbb::blocked_range2d<int>(0, by, 0, bx), [&](const tbb::blocked_range2d<int>& r) {
                auto& mine = made.local();
                for (int yb = r.rows().begin(); yb != r.rows().end(); ++yb) {
                    for (int xb = r.cols().begin(); xb != r.cols().end(); ++xb) {
                        const openvdb::Coord origin(xb * kLeafDim, yb * kLeafDim, zb * kLeafDim);
                        const Eigen::Vector3d bmin =
                            lo + voxel * Eigen::Vector3d(origin.x(), origin.y(), origin.z());
                        const Eigen::Vector3d bmax =
                            bmin + voxel * Eigen::Vector3d::Constant(kLeafDim - 1);
                        std::size_t bracket = n, bracketEnd = n;
                        if (!blockMayBeActive(bmin, bmax, bracket, bracketEnd)) continue;
                        auto leaf = std::make_unique<LeafT>(origin, background, false);
                        bool any = false;
                        if (bracket < n) {
                            // Fast path: the block lies within the slices' range, and the
                            // along-normal and in-plane coordinates are affine in the voxel offset.
                            const double s0 = bmin.dot(g.normal);
                            const Eigen::Vector3d ds = voxel * g.normal;
                            const Eigen::Vector2d m0 = M * bmin;
                            const Eigen::Matrix<double, 2, 3> dm = voxel * M;
                            const int ni = static_cast<int>(
                                std::min<std::int64_t>(kLeafDim, dims[0] - origin.x()));
                            const int nj = static_cast<int>(
                                std::min<std::int64_t>(kLeafDim, dims[1] - origin.y()));
                            const int nk = static_cast<int>(
                                std::min<std::int64_t>(kLeafDim, dims[2] - origin.z()));
                            for (int i = 0; i < ni; ++i) {
                                for (int j = 0; j < nj; ++j) {
                                    const double sij = s0 + ds.x() * i + ds.y() * j;
                                    const double mx = m0.x() + dm(0, 0) * i + dm(0, 1) * j;
                                    const double my = m0.y() + dm(1, 0) * i + dm(1, 1) * j;
                                    const openvdb::Index base = LeafT::coordToOffset(
                                        openvdb::Coord(origin.x() + i, origin.y() + j, origin.z()));
                                    for (int k = 0; k < nk; ++k) {
                                        const double sp = sij + ds.z() * k;
                                        std::size_t ka = bracket;
                                        while (ka + 1 < bracketEnd && g.along[ka + 1] <= sp) ++ka;
                                        const double px = mx + dm(0, 2) * k;
                                        const double py = my + dm(1, 2) * k;
                                        double va = 0, vb = 0;
                                        const bool ina =
                                            sampleSlice(*sorted[ka], px + crOffset[ka].x(),
                                                        py + crOffset[ka].y(), va, mc, mr);
                                        const bool inb =
                                            sampleSlice(*sorted[ka + 1], px + crOffset[ka + 1].x(),
                                                        py + crOffset[ka + 1].y(), vb, mc, mr);
                                        if (!ina && !inb) continue;
                                        const double f = (sp - g.along[ka]) * invGap[ka];
                                        const auto fv = static_cast<float>(va * (1 - f) + vb * f);
                                        if (fv < threshold || fv == background) continue;
                                        leaf->setValueOn(base + static_cast<openvdb::Index>(k), fv);
                                        any = true;
                                    }
                                }
                            }
                            if (any) mine.push_back(std::move(leaf));
                            continue;
                        }
                        for (int i = 0; i < kLeafDim; ++i) {
                            const int x = origin.x() + i;
                            if (x >= dims[0]) break;
                            for (int j = 0; j < kLeafDim; ++j) {
                                const int y = origin.y() + j;
                                if (y >= dims[1]) break;
                                for (int k = 0; k < kLeafDim; ++k) {
                                    const int z = origin.z() + k;
                                    if (z >= dims[2]) break;
                                    const Eigen::Vector3d p = lo + voxel * Eigen::Vector3d(x, y, z);
                                    double v = 0;
                                    if (!valueAt(p, v)) continue;
                                    const auto fv = static_cast<float>(v);
                                    if (fv < threshold || fv == background) continue;
                                    leaf->setValueOn(LeafT::coordToOffset(openvdb::Coord(x, y, z)),
                                                     fv);
                                    any = true;
                                }
                            }
                        }
                        if (any) mine.push_back(std::move(leaf));
                    }
                }
            });
        for (auto& list : made) {
            for (auto& leaf : list) tree.addLeaf(leaf.release());  // the tree takes ownership
            list.clear();
        }
        if (options.progress && !options.progress(static_cast<double>(zb + 1) / bz)) {
            throw Error("resample: cancelled");
        }
    }

    Volume out;
    out.grid = grid;
    out.info = stack.info;
    out.info.backgroundThreshold = threshold;
    out.info.minSliceGap = minGap;
    out.info.maxSliceGap = maxGap;
    out.info.originalSpacing = {g.u.norm(), g.v.norm(), medianGap};
    if (out.info.originalDims[0] == 0) {
        out.info.originalDims = {stack.slices.front().cols, stack.slices.front().rows,
                                 static_cast<std::int64_t>(n)};
    }
    out.info.gantryTiltDeg = tiltDeg;
    writeInfo(out.info, *grid);
    return out;
}

}  // namespace palp::volume
