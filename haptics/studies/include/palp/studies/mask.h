#pragma once
/// @file
/// Binary masks over a map plane and their analysis: Otsu's threshold of a map, thresholding,
/// rasterizing a shape, intersection over union, and a tie-aware choice of the largest score
/// (the automated observer of the virtual experiments).

#include <Eigen/Core>
#include <cstdint>
#include <functional>
#include <span>
#include <vector>

#include "palp/studies/scalar_map.h"

namespace palp::haptics {

/// A binary image over a MapPlane (row-major from the bottom row), 1 = inside.
using Mask = std::vector<std::uint8_t>;

/// Otsu's threshold of the finite pixel values (256 bins between min and max); NaN when the
/// map has fewer than two distinct values.
double otsuThreshold(const ScalarMap& map);
/// Pixels whose value is >= @p threshold (NaN pixels are outside).
Mask thresholdMap(const ScalarMap& map, double threshold);
/// Pixels whose centre satisfies @p inside.
Mask rasterizeMask(const MapPlane& plane,
                   const std::function<bool(const Eigen::Vector3d&)>& inside);
/// |A and B| / |A or B| (1 when both are empty). @throw palp::ValueError for different sizes.
double intersectionOverUnion(const Mask& a, const Mask& b);

/// Index of the largest of @p scores; scores within @p relativeTolerance of the largest
/// (score >= max - tol |max|) are tied and one of them is chosen with a random generator seeded
/// by @p seed, never by position. NaN scores never win. -1 when every score is NaN.
int pickLargest(std::span<const double> scores, double relativeTolerance, std::uint64_t seed);

}  // namespace palp::haptics
