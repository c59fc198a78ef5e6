#pragma once
// palp::fem's int -> std::size_t index conversion: one definition for every source of the module
// (so they also compile together as a unity batch, PALP_UNITY_BUILD).
#include <cstddef>

namespace palp::fem {

/// @p v, a non-negative int index or count, as std::size_t.
inline std::size_t sz(int v) { return static_cast<std::size_t>(v); }

}  // namespace palp::fem
