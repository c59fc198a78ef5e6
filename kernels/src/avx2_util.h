#pragma once
/// @file
/// Internal to first-hit (first_hit.cpp): AVX2 helpers of the vector marches. Defines
/// PALP_RAY_AVX2 where the build can target AVX2 (x86-64, GCC or Clang).

#include <cstdint>

#if (defined(__GNUC__) || defined(__clang__)) && defined(__x86_64__)
#include <immintrin.h>
#endif

#include "lattice_march.h"

#if (defined(__GNUC__) || defined(__clang__)) && defined(__x86_64__)
#define PALP_RAY_AVX2 1

namespace palp::kernels {

// Internal (see ray_sample.h).
namespace {  // NOLINT(google-build-namespaces)

/// a + (b - a) w in each lane, as in lerp8().
__attribute__((target("avx2"), always_inline)) inline __m256 lerpAvx(__m256 a, __m256 b,
                                                                     __m256 w) noexcept {
    return _mm256_add_ps(a, _mm256_mul_ps(_mm256_sub_ps(b, a), w));
}

#define PALP_AVX2_HOT __attribute__((target("avx2"), always_inline)) inline

/// Cell index (runCell()) of block-local positions.
PALP_AVX2_HOT __m256i cellsAvx(__m256 p) noexcept {
    return _mm256_min_epu32(_mm256_cvttps_epi32(p), _mm256_set1_epi32(7));
}

/// Sub-block index (subBlock()) of cells.
PALP_AVX2_HOT __m256i subsAvx(__m256i a, __m256i b, __m256i c) noexcept {
    return _mm256_or_si256(_mm256_or_si256(_mm256_slli_epi32(_mm256_srli_epi32(a, 2), 2),
                                           _mm256_slli_epi32(_mm256_srli_epi32(b, 2), 1)),
                           _mm256_srli_epi32(c, 2));
}

/// Run sample index where the ray leaves the sub-block of cells @p c along one axis, as in
/// subBlockJump().
PALP_AVX2_HOT __m256 exitAvx(__m256i c, __m256 hi, __m256 q, __m256 iv, __m256 far) noexcept {
    const __m256 side =
        _mm256_add_ps(_mm256_cvtepi32_ps(_mm256_slli_epi32(_mm256_srli_epi32(c, 2), 2)), hi);
    return _mm256_add_ps(_mm256_mul_ps(_mm256_sub_ps(side, q), iv), far);
}

PALP_AVX2_HOT __m256i loadAvx(const std::int32_t* p) noexcept {
    return _mm256_load_si256(reinterpret_cast<const __m256i*>(p));
}

PALP_AVX2_HOT void storeAvx(std::int32_t* p, __m256i v) noexcept {
    _mm256_store_si256(reinterpret_cast<__m256i*>(p), v);
}

/// A lattice step blends its samples in cells that can reach the threshold all eight at once
/// (gathers) from this many on, one by one below.
#ifndef PALP_VECTOR_BLEND_LANES
#define PALP_VECTOR_BLEND_LANES 5
#endif
constexpr int kVectorBlendLanes = PALP_VECTOR_BLEND_LANES;

/// The floats at @p base + @p o + @p c in each lane.
PALP_AVX2_HOT __m256 gatherCorner(const float* base, __m256i o, int c) noexcept {
    return _mm256_i32gather_ps(base, _mm256_add_epi32(o, _mm256_set1_epi32(c)), 4);
}

}  // namespace

}  // namespace palp::kernels
#endif
