// Rendering an analytic phantom (phantom.h) as a CT would see it: slices sampled with
// supersampling, counter-based Gaussian noise, in-plane blur and gantry tilt
// (makePhantomSlices), and resampled into a volume (makePhantomVolume).
#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <utility>
#include <vector>

#include "palp/base/bounds.h"
#include "palp/base/error.h"
#include "palp/base/parallel.h"
#include "palp/base/validate.h"
#include "palp/volume/phantom.h"
#include "phantoms/phantom_detail.h"

namespace palp::volume {

namespace {

using detail::kPi;
using detail::mm;

// Counter-based noise: a standard normal variate that depends only on (seed, counter), so the
// result is independent of thread scheduling.
std::uint64_t splitMix64(std::uint64_t x) {
    x += 0x9E3779B97F4A7C15ULL;
    x = (x ^ (x >> 30)) * 0xBF58476D1CE4E5B9ULL;
    x = (x ^ (x >> 27)) * 0x94D049BB133111EBULL;
    return x ^ (x >> 31);
}

double gaussianNoise(std::uint64_t seed, std::uint64_t counter) {
    const std::uint64_t h1 = splitMix64(splitMix64(seed) ^ splitMix64(counter * 2 + 1));
    const std::uint64_t h2 = splitMix64(h1 ^ 0xD1B54A32D192ED03ULL);
    constexpr double kScale = 1.0 / 9007199254740992.0;  // 2^-53
    const double u1 = (static_cast<double>(h1 >> 11) + 0.5) * kScale;
    const double u2 = static_cast<double>(h2 >> 11) * kScale;
    return std::sqrt(-2.0 * std::log(u1)) * std::cos(2.0 * kPi * u2);
}

std::vector<double> gaussianKernel(double sigmaSteps) {
    const int radius = std::max(1, static_cast<int>(std::ceil(3.0 * sigmaSteps)));
    std::vector<double> k(static_cast<std::size_t>(2 * radius + 1));
    double sum = 0;
    for (int i = -radius; i <= radius; ++i) {
        const double w = std::exp(-0.5 * (i * i) / (sigmaSteps * sigmaSteps));
        k[static_cast<std::size_t>(i + radius)] = w;
        sum += w;
    }
    for (double& w : k) w /= sum;
    return k;
}

// One pass of a separable convolution with edge clamping: n lines of length len, element
// (line, i) at data[line * lineStride + i * step].
void convolveLines(std::vector<double>& data, std::vector<double>& scratch,
                   const std::vector<double>& kernel, int lines, int len, std::size_t lineStride,
                   std::size_t step) {
    const int radius = static_cast<int>(kernel.size() / 2);
    scratch.resize(static_cast<std::size_t>(len));
    for (int l = 0; l < lines; ++l) {
        const std::size_t base = static_cast<std::size_t>(l) * lineStride;
        for (int i = 0; i < len; ++i) {
            double acc = 0;
            for (int j = -radius; j <= radius; ++j) {
                const int s = std::clamp(i + j, 0, len - 1);
                acc += kernel[static_cast<std::size_t>(j + radius)] *
                       data[base + static_cast<std::size_t>(s) * step];
            }
            scratch[static_cast<std::size_t>(i)] = acc;
        }
        for (int i = 0; i < len; ++i) {
            data[base + static_cast<std::size_t>(i) * step] = scratch[static_cast<std::size_t>(i)];
        }
    }
}

/// Index range [lo, hi] of cells of size @p step whose centres (k + 1/2) step cover [a, b].
std::pair<std::int64_t, std::int64_t> cellRange(double a, double b, double step) {
    const auto lo = static_cast<std::int64_t>(std::floor(a / step));
    const auto hi = std::max(lo, static_cast<std::int64_t>(std::ceil(b / step)) - 1);
    return {lo, hi};
}

/// Checks what makePhantomSlices needs beyond the phantom's own parameters.
/// @throw ValueError naming the offending field.
void checkSliceSpec(const PhantomSpec& spec, const SliceGeometry& geometry) {
    // Noise and materials within palp's volume-value bounds keep every sample a finite float
    // (a 1e300 HU noise would overflow); spacings within bounds::kSpacing.
    palp::requireWithin("phantom noise sigma", spec.noiseSigmaHu, bounds::kVolumeSpread);
    palp::requireWithin("phantom blur sigma", spec.blurSigma, bounds::kSpan, {1e3, "mm"});
    palp::requireWithin("phantom margin", spec.margin, bounds::kSpan, {1e3, "mm"});
    if (spec.supersample < 1 || spec.supersample > 8) {
        throw ValueError("phantom supersample: expected 1 to 8, found " +
                         std::to_string(spec.supersample));
    }
    palp::requireWithin("phantom pixel spacing", geometry.pixelSpacing, bounds::kSpacing,
                        {1e3, "mm"});
    palp::requireWithin("phantom slice spacing", geometry.sliceSpacing, bounds::kSpacing,
                        {1e3, "mm"});
    for (double g : geometry.sliceGaps) {
        palp::requireWithin("phantom slice gap", g, bounds::kSpacing, {1e3, "mm"});
    }
    palp::requireWithin("phantom slice thickness", geometry.sliceThickness, bounds::kSpan,
                        {1e3, "mm"});
    // The in-plane blur kernel spans 6 sigma in pixels: bounded so the work per pixel is.
    if (spec.blurSigma > 100 * geometry.pixelSpacing) {
        throwExpected("phantom blur sigma",
                      "at most 100 pixel spacings (" + mm(100 * geometry.pixelSpacing) + ")",
                      mm(spec.blurSigma));
    }
    if (!(std::abs(geometry.tiltDeg) < 60)) {
        throw ValueError("phantom gantry tilt: expected less than 60 degrees, found " +
                         formatValue(geometry.tiltDeg));
    }
    // Guards the integer conversions below against absurd spacings.
    const double smallest =
        std::min({geometry.pixelSpacing, geometry.sliceSpacing,
                  geometry.sliceGaps.empty()
                      ? geometry.sliceSpacing
                      : *std::min_element(geometry.sliceGaps.begin(), geometry.sliceGaps.end())});
    if (smallest < 1e-6 || geometry.pixelSpacing > 0.1 || spec.margin > 0.1) {
        throw ValueError(
            "phantom: expected spacings from 0.001 mm to 100 mm and a margin up to 100 mm, found "
            "pixel " +
            mm(geometry.pixelSpacing) + ", smallest gap " + mm(smallest) + ", margin " +
            mm(spec.margin));
    }
}

/// Centres along z of slices @p gaps apart (cycled; divided by cos tilt @p ct) covering
/// [@p zLo, @p zHi).
std::vector<double> sliceCentres(double zLo, double zHi, const std::vector<double>& gaps,
                                 double ct) {
    std::vector<double> zs;
    const double dz0 = gaps[0] / ct;
    double z = (std::floor(zLo / dz0) + 0.5) * dz0;
    zs.push_back(z);
    for (std::size_t k = 0;; ++k) {
        const double dz = gaps[k % gaps.size()] / ct;
        if (z + 0.5 * dz >= zHi) break;
        z += dz;
        zs.push_back(z);
    }
    return zs;
}

}  // namespace

SliceStack makePhantomSlices(const PhantomSpec& spec, const SliceGeometry& geometry) {
    const Phantom phantom(spec.params);
    checkSliceSpec(spec, geometry);
    const std::vector<double> gaps = geometry.sliceGaps.empty()
                                         ? std::vector<double>{geometry.sliceSpacing}
                                         : geometry.sliceGaps;
    const double minGap = *std::min_element(gaps.begin(), gaps.end());

    const double t = geometry.tiltDeg * kPi / 180.0;
    const double ct = std::cos(t), st = std::sin(t);
    const double p = geometry.pixelSpacing;
    const Eigen::Vector3d colDir(1, 0, 0);
    const Eigen::Vector3d rowDir(0, ct, -st);
    const Eigen::Vector3d normal = colDir.cross(rowDir);  // (0, sin t, cos t)

    WorldBox dom = phantom.bounds();
    dom.min.array() -= spec.margin;
    dom.max.array() += spec.margin;
    const auto [cx0, cx1] = cellRange(dom.min.x(), dom.max.x(), p);
    const auto [ry0, ry1] = cellRange(dom.min.y(), dom.max.y(), p * ct);
    const std::int64_t cols = cx1 - cx0 + 1;
    const std::int64_t rows = ry1 - ry0 + 1;
    const double x0 = (static_cast<double>(cx0) + 0.5) * p;
    const double y0 = (static_cast<double>(ry0) + 0.5) * p * ct;

    // Slice k's pixel (0, 0) is at (x0, y0, z_k); a world point (y, z) lies on the slice with
    // z_k = z + (y - y0) tan t, so the z_k must cover this range.
    const double yExtent = static_cast<double>(rows - 1) * p * ct;
    const double shift = yExtent * std::tan(t);
    const double zLo = dom.min.z() + std::min(0.0, shift);
    const double zHi = dom.max.z() + std::max(0.0, shift);
    const std::uint64_t maxSlices =
        static_cast<std::uint64_t>(std::ceil((zHi - zLo) / (minGap / ct))) + 2;
    constexpr std::uint64_t kMaxPixels = std::uint64_t{1} << 28;
    if (static_cast<std::uint64_t>(cols * rows) * maxSlices > kMaxPixels) {
        throw ValueError("phantom: expected at most 2^28 pixels, found " + std::to_string(cols) +
                         "x" + std::to_string(rows) + "x" + std::to_string(maxSlices) +
                         "; choose a larger pixel or slice spacing");
    }
    const std::vector<double> zs = sliceCentres(zLo, zHi, gaps, ct);

    SliceStack stack;
    stack.slices.resize(zs.size());
    const int n = spec.supersample;
    const double thickness = geometry.sliceThickness > 0 ? geometry.sliceThickness : minGap;
    // Partial volume: sub-sample offsets (in-plane in pixels, along the normal in metres), then
    // Gaussian blur along the normal by planes every sigma/2 and in-plane on the pixel lattice.
    std::vector<double> subOffsets(static_cast<std::size_t>(n));
    for (int i = 0; i < n; ++i) subOffsets[static_cast<std::size_t>(i)] = (i + 0.5) / n - 0.5;
    std::vector<std::pair<double, double>> planes;  // (offset along normal in m, weight)
    if (spec.blurSigma > 0) {
        const std::vector<double> k = gaussianKernel(2.0);  // step sigma/2, radius 3 sigma
        const int radius = static_cast<int>(k.size() / 2);
        for (int j = -radius; j <= radius; ++j) {
            planes.emplace_back(j * 0.5 * spec.blurSigma, k[static_cast<std::size_t>(j + radius)]);
        }
    } else {
        planes.emplace_back(0.0, 1.0);
    }
    const std::vector<double> inPlaneKernel =
        spec.blurSigma > 0 ? gaussianKernel(spec.blurSigma / p) : std::vector<double>{};
    const auto ncols = static_cast<int>(cols);
    const auto nrows = static_cast<int>(rows);
    const Eigen::Vector3d colStep = p * colDir;
    const Eigen::Vector3d rowStep = p * rowDir;
    const double subWeight = 1.0 / (n * n * n);

    palp::parallelFor(
        tbb::blocked_range<std::size_t>(0, zs.size()),
        [&](const tbb::blocked_range<std::size_t>& range) {
            std::vector<double> img;
            std::vector<double> scratch;
            for (std::size_t k = range.begin(); k != range.end(); ++k) {
                Slice& s = stack.slices[k];
                s.position = Eigen::Vector3d(x0, y0, zs[k]);
                s.colStep = colStep;
                s.rowStep = rowStep;
                s.cols = ncols;
                s.rows = nrows;
                s.source = "phantom slice " + std::to_string(k);
                img.assign(static_cast<std::size_t>(ncols) * static_cast<std::size_t>(nrows), 0.0);
                for (int r = 0; r < nrows; ++r) {
                    for (int c = 0; c < ncols; ++c) {
                        const Eigen::Vector3d centre = s.position + c * colStep + r * rowStep;
                        double acc = 0;
                        for (const auto& [offset, weight] : planes) {
                            double box = 0;
                            for (double a : subOffsets) {
                                for (double b : subOffsets) {
                                    for (double d : subOffsets) {
                                        box += phantom.valueAt(centre +
                                                               (offset + d * thickness) * normal +
                                                               a * colStep + b * rowStep);
                                    }
                                }
                            }
                            acc += weight * box * subWeight;
                        }
                        img[static_cast<std::size_t>(r) * static_cast<std::size_t>(ncols) +
                            static_cast<std::size_t>(c)] = acc;
                    }
                }
                if (!inPlaneKernel.empty()) {
                    convolveLines(img, scratch, inPlaneKernel, nrows, ncols,
                                  static_cast<std::size_t>(ncols), 1);
                    convolveLines(img, scratch, inPlaneKernel, ncols, nrows, 1,
                                  static_cast<std::size_t>(ncols));
                }
                s.values.resize(img.size());
                const std::uint64_t base = static_cast<std::uint64_t>(k) * img.size();
                for (std::size_t i = 0; i < img.size(); ++i) {
                    double v = img[i];
                    if (spec.noiseSigmaHu > 0)
                        v += spec.noiseSigmaHu * gaussianNoise(spec.seed, base + i);
                    s.values[i] = static_cast<float>(v);
                }
            }
        });

    VolumeInfo& info = stack.info;
    info.modality = "CT";
    info.valueUnits = "HU";
    info.sourceFormat = "phantom";
    info.sourceDescription = "phantom " + phantom.description() +
                             " noise=" + formatValue(spec.noiseSigmaHu) +
                             "HU blur=" + mm(spec.blurSigma) + " supersample=" + std::to_string(n) +
                             " seed=" + std::to_string(spec.seed);
    info.originalDims = {cols, rows, static_cast<std::int64_t>(zs.size())};
    std::vector<double> sortedGaps;
    for (std::size_t k = 1; k < zs.size(); ++k) sortedGaps.push_back((zs[k] - zs[k - 1]) * ct);
    std::sort(sortedGaps.begin(), sortedGaps.end());
    const double medianGap = sortedGaps.empty() ? thickness : sortedGaps[sortedGaps.size() / 2];
    info.originalSpacing = {p, p, medianGap};
    info.minSliceGap = sortedGaps.empty() ? 0 : sortedGaps.front();
    info.maxSliceGap = sortedGaps.empty() ? 0 : sortedGaps.back();
    info.gantryTiltDeg = std::abs(geometry.tiltDeg);
    info.backgroundThreshold = -900;
    return stack;
}

Volume makePhantomVolume(const PhantomSpec& spec) {
    palp::requireWithin("phantom voxel size", spec.voxelSize, bounds::kSpacing, {1e3, "mm"});
    SliceGeometry geometry;
    geometry.pixelSpacing = spec.voxelSize;
    geometry.sliceSpacing = spec.voxelSize;
    geometry.sliceThickness = spec.voxelSize;
    const SliceStack stack = makePhantomSlices(spec, geometry);
    ResampleOptions options;
    options.voxelSize = spec.voxelSize;
    options.backgroundThreshold = -900.0f;
    Volume vol = resample(stack, options);
    vol.info.modality = "CT";
    vol.info.valueUnits = "HU";
    vol.info.sourceFormat = "phantom";
    vol.info.sourceDescription = stack.info.sourceDescription + " voxel=" + mm(spec.voxelSize);
    writeInfo(vol.info, *vol.grid);
    return vol;
}

}  // namespace palp::volume
