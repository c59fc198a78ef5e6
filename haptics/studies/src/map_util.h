#pragma once
// Small helpers shared by the stiffness maps and their writers (internal, not installed): one
// definition each, so the sources also compile together as a unity batch (PALP_UNITY_BUILD).
#include <cmath>
#include <cstdio>
#include <limits>
#include <string>

namespace palp::haptics {

/// The value of a map cell, mask or sample that holds nothing.
inline constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

/// @p x as `%.6g`, for SVG coordinates and labels.
inline std::string num(double x) {
    char buf[32];
    std::snprintf(buf, sizeof buf, "%.6g", x);
    return buf;
}

/// The scaled position in [0, 1] of @p v between @p lo and @p hi (0 when the range is empty).
inline double unit(double v, double lo, double hi) {
    if (!std::isfinite(lo) || !std::isfinite(hi)) return 0;
    return hi > lo ? (v - lo) / (hi - lo) : 0.0;
}

}  // namespace palp::haptics
