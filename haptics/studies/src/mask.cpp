#include "palp/studies/mask.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <random>
#include <string>

#include "map_util.h"
#include "palp/base/error.h"

namespace palp::haptics {

double otsuThreshold(const ScalarMap& map) {
    const std::vector<double> values = map.finiteValues();
    if (values.empty()) return kNaN;
    const auto [mn, mx] = std::minmax_element(values.begin(), values.end());
    const double lo = *mn, hi = *mx;
    if (!(hi > lo)) return kNaN;
    constexpr int kBins = 256;
    std::array<double, kBins> hist{};
    for (double x : values) {
        const int b = std::min(kBins - 1, static_cast<int>((x - lo) / (hi - lo) * kBins));
        hist[static_cast<std::size_t>(b)] += 1;
    }
    const double total = static_cast<double>(values.size());
    double sumAll = 0;
    for (int b = 0; b < kBins; ++b) sumAll += b * hist[static_cast<std::size_t>(b)];
    double w0 = 0, sum0 = 0, best = -1;
    int bestFirst = 0, bestLast = 0;
    for (int b = 0; b < kBins - 1; ++b) {
        w0 += hist[static_cast<std::size_t>(b)];
        sum0 += b * hist[static_cast<std::size_t>(b)];
        const double w1 = total - w0;
        if (w0 == 0 || w1 == 0) continue;
        const double m0 = sum0 / w0, m1 = (sumAll - sum0) / w1;
        const double between = w0 * w1 * (m0 - m1) * (m0 - m1);
        if (between > best * (1 + 1e-12)) {
            best = between;
            bestFirst = bestLast = b;
        } else if (between >= best * (1 - 1e-12)) {
            bestLast = b;  // empty bins between the classes: a plateau of equal variance
        }
    }
    // The middle of the plateau (the gap between the classes), at a bin edge.
    return lo + (0.5 * (bestFirst + bestLast) + 1) * (hi - lo) / kBins;
}

Mask thresholdMap(const ScalarMap& map, double threshold) {
    Mask m(static_cast<std::size_t>(map.cols()) * static_cast<std::size_t>(map.rows()), 0);
    for (int r = 0; r < map.rows(); ++r) {
        for (int c = 0; c < map.cols(); ++c) {
            const double x = map.at(c, r);
            m[static_cast<std::size_t>(r) * static_cast<std::size_t>(map.cols()) +
              static_cast<std::size_t>(c)] = (std::isfinite(x) && x >= threshold) ? 1 : 0;
        }
    }
    return m;
}

Mask rasterizeMask(const MapPlane& plane,
                   const std::function<bool(const Eigen::Vector3d&)>& inside) {
    validateMapPlane(plane);
    const int cols = plane.cols(), rows = plane.rows();
    Mask m(static_cast<std::size_t>(cols) * static_cast<std::size_t>(rows), 0);
    for (int r = 0; r < rows; ++r) {
        for (int c = 0; c < cols; ++c) {
            m[static_cast<std::size_t>(r) * static_cast<std::size_t>(cols) +
              static_cast<std::size_t>(c)] = inside(plane.pixelCentre(c, r)) ? 1 : 0;
        }
    }
    return m;
}

double intersectionOverUnion(const Mask& a, const Mask& b) {
    if (a.size() != b.size()) {
        throw ValueError("intersectionOverUnion: expected masks of the same size, found " +
                         std::to_string(a.size()) + " and " + std::to_string(b.size()) + " pixels");
    }
    std::size_t both = 0, either = 0;
    for (std::size_t i = 0; i < a.size(); ++i) {
        both += (a[i] && b[i]) ? 1u : 0u;
        either += (a[i] || b[i]) ? 1u : 0u;
    }
    return either ? static_cast<double>(both) / static_cast<double>(either) : 1.0;
}

int pickLargest(std::span<const double> scores, double relativeTolerance, std::uint64_t seed) {
    double best = -std::numeric_limits<double>::infinity();
    bool any = false;
    for (double s : scores) {
        if (std::isfinite(s)) {
            best = std::max(best, s);
            any = true;
        }
    }
    if (!any) return -1;
    const double cut = best - std::abs(relativeTolerance) * std::abs(best);
    std::vector<int> tied;
    for (std::size_t i = 0; i < scores.size(); ++i) {
        if (std::isfinite(scores[i]) && scores[i] >= cut) tied.push_back(static_cast<int>(i));
    }
    if (tied.size() == 1) return tied.front();
    std::mt19937_64 rng(seed);
    std::uniform_int_distribution<std::size_t> pick(0, tied.size() - 1);
    return tied[pick(rng)];
}

}  // namespace palp::haptics
