#include <Eigen/Dense>
#include <algorithm>
#include <array>
#include <atomic>
#include <cmath>
#include <exception>
#include <limits>
#include <memory>
#include <numeric>
#include <sstream>

#include "lazy_stack.h"
#include "palp/base/bounds.h"
#include "palp/base/error.h"
#include "palp/base/parallel.h"
#include "palp/base/validate.h"
#include "palp/volume/resample_options.h"
#include "resample/leaf_sink.h"
#include "resample/slice_sampler.h"

namespace palp::volume {

namespace {

using namespace detail;

std::string vecStr(const Eigen::Vector3d& v) {
    std::ostringstream os;
    os << "(" << v.x() << ", " << v.y() << ", " << v.z() << ")";
    return os.str();
}

/// With @p resident false the slices' values are not there yet (a lazy stack): only the
/// geometry is checked, the values as they are decoded.
StackGeometry analyse(const SliceStack& stack, bool resident) {
    if (stack.slices.empty()) throw ValueError("resample: expected at least one slice, found none");
    if (resident) checkStackValues(stack);
    StackGeometry g;
    const Slice& first = stack.slices.front();
    g.u = first.colStep;
    g.v = first.rowStep;
    for (const Slice& s : stack.slices) {
        if (s.cols <= 0 || s.rows <= 0 ||
            (resident && s.values.size() !=
                             static_cast<std::size_t>(s.cols) * static_cast<std::size_t>(s.rows))) {
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

std::string mmStr(double metres) { return formatValue(metres * 1e3); }

/// The world axis @p dir (a unit vector) lies along, or -1 when it is off every axis by more
/// than kNativeAxisSin (sine of the angle).
constexpr double kNativeAxisSin = 1e-5;
int worldAxisOf(const Eigen::Vector3d& dir) {
    int a = 0;
    dir.cwiseAbs().maxCoeff(&a);
    const double off = std::sqrt(std::max(0.0, 1.0 - dir[a] * dir[a]));
    return off <= kNativeAxisSin ? a : -1;
}

/// The lattice steps (metres, along world x, y, z) of native spacing: the column step, the row
/// step and the slice gap, each on the world axis it lies along. Single slices take the smaller
/// in-plane step as their thickness.
/// @throw ValueError when the slices' rows, columns or normal are off the world axes, the slices
///        are stacked with a tilt (or shifted in plane), or their gaps are uneven (a slice more
///        than kNativeGapTolerance of the mean gap off its even position).
Eigen::Vector3d nativeSteps(const SliceStack& stack, const StackGeometry& g) {
    const Slice& first = stack.slices[g.order.front()];
    const std::string what = "resample: native spacing";
    const int au = worldAxisOf(g.u.normalized()), av = worldAxisOf(g.v.normalized());
    const int an = worldAxisOf(g.normal);
    if (au < 0 || av < 0 || an < 0) {
        throwExpected(what + " (" + first.source + ")",
                      "rows, columns and slice normal along the patient axes (within 0.0006 "
                      "degrees), or a voxel size to resample to",
                      "column step " + vecStr(g.u) + " m, row step " + vecStr(g.v) + " m, normal " +
                          vecStr(g.normal));
    }
    const std::size_t n = g.order.size();
    Eigen::Vector3d step;
    step[au] = g.u.norm();
    step[av] = g.v.norm();
    step[an] = std::min(g.u.norm(), g.v.norm());
    if (n > 1) {
        const double gap = (g.along.back() - g.along.front()) / static_cast<double>(n - 1);
        const double inPlaneTol = 1e-3 * std::min(g.u.norm(), g.v.norm());
        for (std::size_t k = 0; k < n; ++k) {
            const Slice& s = stack.slices[g.order[k]];
            const Eigen::Vector3d d = s.position - first.position;
            const Eigen::Vector3d shift = d - d.dot(g.normal) * g.normal;
            if (shift.norm() > inPlaneTol) {
                throwExpected(
                    what + " (" + s.source + ")",
                    "slices stacked along their normal (no gantry tilt), or a voxel "
                    "size to resample to",
                    "a shift of " + mmStr(shift.norm()) + " mm in plane from " + first.source);
            }
            const double off = g.along[k] - (g.along.front() + static_cast<double>(k) * gap);
            if (std::abs(off) > kNativeGapTolerance * gap) {
                double lo = std::numeric_limits<double>::infinity(), hi = 0;
                for (std::size_t i = 1; i < n; ++i) {
                    lo = std::min(lo, g.along[i] - g.along[i - 1]);
                    hi = std::max(hi, g.along[i] - g.along[i - 1]);
                }
                throwExpected(what + " (" + s.source + ")",
                              "evenly spaced slices (each within 1 % of the mean gap of " +
                                  mmStr(gap) + " mm), or a voxel size to resample to",
                              "gaps from " + mmStr(lo) + " to " + mmStr(hi) + " mm, this slice " +
                                  mmStr(off) + " mm off");
            }
        }
        step[an] = gap;
    }
    for (int a = 0; a < 3; ++a)
        palp::requireWithin(what + ": step", step[a], bounds::kSpacing, {1e3, "mm"});
    return step;
}

/// Bounds the pixel centres of every slice, crops and checks size. An isotropic lattice gets a
/// voxel of margin; a native one (@p native) none, so that its voxels are the pixels, and a crop
/// keeps it on the pixel centres.
Lattice planLattice(const SliceStack& stack, const StackGeometry& g, const Eigen::Vector3d& step,
                    bool native, const ResampleOptions& options) {
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
    if (!native) {
        const double voxel = step.x();
        if (n == 1) {  // a single slice is a slab one voxel thick
            lo -= 0.5 * voxel * g.normal.cwiseAbs();
            hi += 0.5 * voxel * g.normal.cwiseAbs();
        }
        // One voxel of margin on every side, filled by extending the edge pixels, so that
        // trilinear sampling of the grid is exact up to the outermost pixel centres (a lattice
        // cell around a point on the data's edge has corners up to one voxel away along each
        // axis). Shifting by a whole voxel keeps the lattice of an axis-aligned source on its
        // pixel centres.
        lo -= Eigen::Vector3d::Constant(voxel);
        hi += Eigen::Vector3d::Constant(voxel);
    }
    if (options.crop) {
        Eigen::Vector3d cropLo = options.crop->min;
        if (native) {  // the first pixel centre inside the box
            for (int a = 0; a < 3; ++a) {
                const double k = std::ceil((cropLo[a] - lo[a]) / step[a] - 1e-6);
                cropLo[a] = lo[a] + std::max(k, 0.0) * step[a];
            }
        }
        lo = lo.cwiseMax(cropLo);
        hi = hi.cwiseMin(options.crop->max);
        if ((hi.array() < lo.array()).any()) {
            throw ValueError("resample: the crop box " + vecStr(options.crop->min) + " - " +
                             vecStr(options.crop->max) + " m does not overlap the scan (" +
                             vecStr(lo) + " - " + vecStr(hi) + ")");
        }
    }
    Lattice lat;
    lat.lo = lo;
    lat.step = step;
    std::array<std::int64_t, 3>& dims = lat.dims;
    for (int a = 0; a < 3; ++a) {
        dims[static_cast<std::size_t>(a)] =
            static_cast<std::int64_t>(std::floor((hi[a] - lo[a]) / step[a] + 1e-6)) + 1;
    }
    const long double total = static_cast<long double>(dims[0]) * dims[1] * dims[2];
    if (total > static_cast<long double>(options.maxVoxels)) {
        const std::string spacing =
            native ? "native spacing (" + mmStr(step.x()) + " x " + mmStr(step.y()) + " x " +
                         mmStr(step.z()) + " mm)"
                   : "a voxel size of " + std::to_string(step.x() * 1e3) + " mm";
        throw ValueError("resample: " + spacing + " gives " + std::to_string(dims[0]) + "x" +
                         std::to_string(dims[1]) + "x" + std::to_string(dims[2]) +
                         " voxels, more than the limit of " + std::to_string(options.maxVoxels) +
                         "; choose a larger voxel size");
    }
    return lat;
}

}  // namespace

void checkResampleOptions(const ResampleOptions& options) {
    if (options.voxelSize) {
        palp::requireWithin("resample: voxel size", *options.voxelSize, bounds::kSpacing,
                            {1e3, "mm"});
        if (options.nativeSpacing) {
            throwExpected("resample: voxel size", "none with native spacing",
                          formatValue(*options.voxelSize * 1e3) + " mm");
        }
    }
    if (options.backgroundThreshold) {
        palp::requireWithin("resample: background threshold",
                            static_cast<double>(*options.backgroundThreshold),
                            bounds::kVolumeValue);
    }
    if (options.crop) {
        for (int a = 0; a < 3; ++a) {
            std::string axis = "[";  // appended, not "[" + ... (GCC 12's -Wrestrict misfires)
            axis += std::to_string(a);
            axis += ']';
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
    if (info.modality == "CT") return -900.0f;
    // MR values may be signed (field maps, phase): none is cut. A source that does not say what
    // it is (NIfTI, NRRD, MetaImage, arrays) keeps 0, and what it loses is counted.
    return info.modality == "MR" ? kNoBackgroundThreshold : 0.0f;
}

float backgroundValueFor(const VolumeInfo& info, float threshold) {
    const float preferred = info.modality == "CT" ? -1000.0f : 0.0f;
    return threshold <= kNoBackgroundThreshold ? preferred : std::min(preferred, threshold);
}

namespace {

/// The values of @p s below @p threshold other than @p background: values the grid loses.
std::uint64_t countBelow(const Slice& s, float threshold, float background) {
    std::uint64_t n = 0;
    for (const float v : s.values) n += v < threshold && v != background ? 1 : 0;
    return n;
}

/// Decodes the slices of a lazy stack as fillTree's window asks, checks them, and releases
/// those it has passed.
class LazyWindow {
  public:
    LazyWindow(LazySliceStack& lazy, SliceSampler& sampler, float threshold, float background)
        : mLazy(lazy),
          mSampler(sampler),
          mThreshold(threshold),
          mBackground(background),
          mResident(sampler.sliceCount(), 0),
          mDecoded(sampler.sliceCount(), 0) {}

    void operator()(std::size_t releaseBelow, std::size_t lo, std::size_t hi) {
        for (std::size_t k = mReleased; k < releaseBelow; ++k) release(k);
        mReleased = std::max(mReleased, releaseBelow);
        std::vector<std::size_t> todo;
        for (std::size_t k = lo; k <= hi; ++k)
            if (!mResident[k]) todo.push_back(k);
        decode(todo, false);
    }

    /// Decodes (and checks) the slices never decoded, one at a time per thread, and releases
    /// every slice.
    void finish() {
        for (std::size_t k = 0; k < mResident.size(); ++k) release(k);
        mSpare = {};
        std::vector<std::size_t> todo;
        for (std::size_t k = 0; k < mDecoded.size(); ++k)
            if (!mDecoded[k]) todo.push_back(k);
        decode(todo, true);
    }

  private:
    /// Keeps the released slice's buffer for the next slice to decode (the band holds the same
    /// number of same-sized slices all along): no allocation, page faults or zero-filling of a
    /// fresh buffer per slice.
    void release(std::size_t k) {
        if (!mResident[k]) return;
        mSpare.push_back(std::move(slice(k).values));
        slice(k).values = {};
        mResident[k] = 0;
    }

    Slice& slice(std::size_t k) { return mLazy.stack.slices[mSampler.stackIndex(k)]; }

    /// Decodes sorted slices @p todo in parallel; when several fail, the first one's error (by
    /// position along the normal) is thrown.
    void decode(const std::vector<std::size_t>& todo, bool thenRelease) {
        for (const std::size_t k : todo) {
            if (mSpare.empty() || thenRelease) break;
            slice(k).values = std::move(mSpare.back());
            mSpare.pop_back();
        }
        std::vector<std::exception_ptr> errors(todo.size());
        palp::parallelForEach(
            std::size_t{0}, todo.size(),
            [&](std::size_t i) {
                const std::size_t k = todo[i];
                const std::size_t index = mSampler.stackIndex(k);
                Slice& s = slice(k);
                try {
                    const std::int32_t cols = s.cols, rows = s.rows;
                    const bool checked = mLazy.decode(index, s);
                    if (s.cols != cols || s.rows != rows ||
                        s.values.size() !=
                            static_cast<std::size_t>(cols) * static_cast<std::size_t>(rows)) {
                        throw FormatError(s.source + ": expected " + std::to_string(cols) + "x" +
                                          std::to_string(rows) + " values, found " +
                                          std::to_string(s.values.size()));
                    }
                    try {
                        if (!checked) checkSliceValues(s, index);
                    } catch (const ValueError& e) {
                        throw FormatError(e.what());  // the file is at fault
                    }
                    // A slice is decoded again when the band comes back to it: count it once.
                    if (!mDecoded[k]) mBelow += countBelow(s, mThreshold, mBackground);
                    if (thenRelease) {
                        std::vector<float>().swap(s.values);
                    } else {
                        mSampler.sliceLoaded(k);
                    }
                } catch (...) {
                    std::vector<float>().swap(s.values);
                    errors[i] = std::current_exception();
                }
            },
            std::size_t{1});
        for (const std::exception_ptr& e : errors)
            if (e) std::rethrow_exception(e);
        for (const std::size_t k : todo) {
            mDecoded[k] = 1;
            mResident[k] = thenRelease ? 0 : 1;
        }
    }

  public:
    /// Source values below the threshold (not the background) in the slices decoded so far.
    std::uint64_t below() const { return mBelow; }

  private:
    LazySliceStack& mLazy;
    SliceSampler& mSampler;
    float mThreshold, mBackground;
    std::atomic<std::uint64_t> mBelow{0};
    std::vector<char> mResident, mDecoded;   // by sorted slice
    std::vector<std::vector<float>> mSpare;  // buffers of released slices
    std::size_t mReleased = 0;
};

}  // namespace

namespace detail {

void checkLazyValues(const LazySliceStack& lazy) {
    if (lazy.decode) return;
    try {
        checkStackValues(lazy.stack);
    } catch (const ValueError& e) {
        throw FormatError(e.what());  // the file is at fault, as readStack() says
    }
}

VolumeInfo resampleInto(const SliceStack& stack, const ResampleOptions& options, LeafSink& sink,
                        const FillPaths& paths, LazySliceStack* lazy) {
    const bool resident = lazy == nullptr || !lazy->decode;
    const StackGeometry g = analyse(stack, resident);
    const std::size_t n = g.order.size();
    const StackSpacing spacing = measureSpacing(stack, g);
    const Eigen::Vector3d step =
        options.nativeSpacing ? nativeSteps(stack, g)
                              : Eigen::Vector3d::Constant(chooseVoxelSize(g, spacing, options));
    const Lattice lat = planLattice(stack, g, step, options.nativeSpacing, options);

    const float threshold =
        options.backgroundThreshold.value_or(defaultBackgroundThreshold(stack.info));
    const float background = backgroundValueFor(stack.info, threshold);
    sink.start(step, lat.lo, background);

    SliceSampler sampler(stack, g, step, threshold, resident);
    const FillContext ctx{sampler,
                          g,
                          lat,
                          threshold,
                          background,
                          paths.referenceOnly,
                          paths.scalarRows,
                          paths.perBlockRows,
                          sink};
    std::uint64_t below = 0;
    if (resident) {
        fillTree(ctx, options.progress);
        std::vector<std::uint64_t> perSlice(stack.slices.size(), 0);
        palp::parallelForEach(
            std::size_t{0}, perSlice.size(),
            [&](std::size_t k) {
                perSlice[k] = countBelow(stack.slices[k], threshold, background);
            },
            std::size_t{1});
        below = std::accumulate(perSlice.begin(), perSlice.end(), std::uint64_t{0});
    } else {
        LazyWindow window(*lazy, sampler, threshold, background);
        fillTree(ctx, options.progress,
                 [&](std::size_t releaseBelow, std::size_t lo, std::size_t hi) {
                     window(releaseBelow, lo, hi);
                 });
        window.finish();
        below = window.below();
    }

    VolumeInfo info = stack.info;
    info.backgroundThreshold = threshold;
    info.valuesBelowThreshold = below;
    info.minSliceGap = spacing.minGap;
    info.maxSliceGap = spacing.maxGap;
    info.originalSpacing = {g.u.norm(), g.v.norm(), spacing.medianGap};
    if (info.originalDims[0] == 0) {
        info.originalDims = {stack.slices.front().cols, stack.slices.front().rows,
                             static_cast<std::int64_t>(n)};
    }
    // The geometry gives the angle; a DICOM Gantry/Detector Tilt (0018,1120) gives its sign,
    // which the metadata keeps as the tag says.
    info.gantryTiltDeg = stack.info.gantryTiltDeg < 0 ? -spacing.tiltDeg : spacing.tiltDeg;
    return info;
}

}  // namespace detail

}  // namespace palp::volume
