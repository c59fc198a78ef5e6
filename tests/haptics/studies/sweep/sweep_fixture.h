#pragma once
// A small sweep the sweep tests share: a 7^3-node cube, 20 ms per sample, groups of 3, every
// kind of range (uniform, log, integer, values, fixed).
#include <string>

namespace palp::test {

inline std::string smallRanges(const std::string& extra = "") {
    return R"({"palp_sweep_ranges": 1, "mesh": {"nodes": 7, "spacing_mm": 5}, "duration_s": 0.02,
  "adaptivity_per_reference": 3, "variables": {
    "strain": {"min": 0.01, "max": 0.06}, "frequency": {"min": 10, "max": 40},
    "contact": {"min": 0, "max": 8, "integer": true},
    "youngs": {"min": 2000, "max": 20000, "scale": "log"}, "poisson": {"min": 0.3, "max": 0.45},
    "density": {"value": 1000}, "damping": {"min": 2, "max": 20}, "lod": {"values": [1, 2]},
    "primary": {"min": 3, "max": 12, "integer": true}, "rate": {"min": 50, "max": 500},
    "coupling": {"values": [0, 1]})" +
           extra + "}}";
}

}  // namespace palp::test
