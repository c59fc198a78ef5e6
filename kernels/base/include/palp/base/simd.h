#pragma once
/// @file
/// Whether palp's hand-written AVX2/FMA paths may run. They are chosen at run time (the build
/// targets baseline x86-64) and each computes what its portable path computes: bit for bit
/// where it keeps the portable order of operations (the ray and resampling kernels), to
/// rounding where it fuses multiplies and adds (the FEM products).
///
/// The environment variable PALP_SIMD=off turns them off on any CPU, so the portable paths are
/// tested on machines that have AVX2 (the test suite runs the agreement tests both ways).
///
/// @par Threading
/// Read once, at the first call (a function-local static); call it off the servo thread first
/// (the solvers' constructors do), then it is a load of a constant.

namespace palp {

/// True when the CPU has AVX2 and PALP_SIMD is not "off" (or "0").
bool avx2Enabled() noexcept;

/// True when avx2Enabled() and the CPU also has FMA.
bool avx2FmaEnabled() noexcept;

}  // namespace palp
