#pragma once
/// @file
/// Internal to palp_volume: what the phantom's analytic model (phantom.cpp) and its CT-like
/// rendering into slices and volumes (phantom_slices.cpp) share.
#include <cstdio>
#include <numbers>
#include <string>

namespace palp::volume::detail {

inline constexpr double kPi = std::numbers::pi;

/// @p metres written in millimetres ("2.5mm"), for messages.
inline std::string mm(double metres) {
    char buf[64];
    std::snprintf(buf, sizeof buf, "%gmm", metres * 1e3);
    return buf;
}

}  // namespace palp::volume::detail
