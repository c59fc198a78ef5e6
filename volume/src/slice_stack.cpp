#include "palp/volume/slice_stack.h"

#include <algorithm>
#include <cstddef>
#include <string>

#include "lazy_stack.h"
#include "palp/base/bounds.h"

namespace palp::volume {

SliceStack stackFromAffine(const std::vector<float>& values,
                           const std::array<std::int64_t, 3>& dims, const Eigen::Matrix3d& axes,
                           const Eigen::Vector3d& origin, const std::string& source) {
    SliceStack stack;
    const auto nx = static_cast<std::size_t>(dims[0]);
    const auto ny = static_cast<std::size_t>(dims[1]);
    const auto nz = static_cast<std::size_t>(dims[2]);
    stack.slices.resize(nz);
    for (std::size_t k = 0; k < nz; ++k) {
        Slice& s = stack.slices[k];
        s.position = origin + static_cast<double>(k) * axes.col(2);
        s.colStep = axes.col(0);
        s.rowStep = axes.col(1);
        s.cols = static_cast<std::int32_t>(nx);
        s.rows = static_cast<std::int32_t>(ny);
        const auto begin = values.begin() + static_cast<std::ptrdiff_t>(k * nx * ny);
        s.values.assign(begin, begin + static_cast<std::ptrdiff_t>(nx * ny));
        s.source = source;
    }
    stack.info.originalDims = dims;
    stack.info.originalSpacing = {axes.col(0).norm(), axes.col(1).norm(), axes.col(2).norm()};
    return stack;
}

namespace detail {

void checkSliceValues(const Slice& s, std::size_t k) {
    // A branch-free pass first (it vectorises; NaN fails both comparisons), the search for the
    // offending value only when there is one.
    // The bounds are floats exactly (+-1e9), so comparing floats is comparing doubles.
    constexpr auto lo = static_cast<float>(bounds::kVolumeValue.min);
    constexpr auto hi = static_cast<float>(bounds::kVolumeValue.max);
    static_assert(static_cast<double>(lo) == bounds::kVolumeValue.min &&
                  static_cast<double>(hi) == bounds::kVolumeValue.max);
    static_assert(!bounds::kVolumeValue.minOpen && !bounds::kVolumeValue.maxOpen);
    bool within = true;
    for (const float v : s.values) within &= (v >= lo) & (v <= hi);
    if (within) return;
    const auto bad = std::find_if(s.values.begin(), s.values.end(), [](float v) {
        return !bounds::kVolumeValue.contains(static_cast<double>(v));
    });
    if (bad == s.values.end()) return;
    const auto at = static_cast<std::size_t>(bad - s.values.begin());
    const auto cols = static_cast<std::size_t>(std::max(s.cols, 1));
    requireWithin(s.source + ": voxel (column " + std::to_string(at % cols) + ", row " +
                      std::to_string(at / cols) + ", slice " + std::to_string(k) + ")",
                  static_cast<double>(*bad), bounds::kVolumeValue);
}

}  // namespace detail

void checkStackValues(const SliceStack& stack) {
    for (std::size_t k = 0; k < stack.slices.size(); ++k)
        detail::checkSliceValues(stack.slices[k], k);
}

}  // namespace palp::volume
