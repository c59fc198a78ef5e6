#pragma once
/// @file
/// TLED's one-point element four cells at a time with AVX2 and FMA (docs/algorithms.md, "Large
/// strain: TLED", "The one-point kernel"); tled.cpp chooses it at run time (palp/base/simd.h).

#include <cstddef>

#if defined(__x86_64__) && (defined(__GNUC__) || defined(__clang__))
#define PALP_TLED_AVX2 1
#endif

namespace palp::fem::detail {

/// The one-point element's constants: @p gradScale = 1 / (4 h), @p area = h^2 / 4, @p mu1 and
/// @p bulk1 the law for E = 1, @p hourglass8 the hourglass spring for E = 1 over 8.
struct OnePointConstants {
    double gradScale, area, mu1, bulk1, hourglass8;
};

#ifdef PALP_TLED_AVX2
/// The one-point element's forces of cells 4 g .. 4 g + 3 of a lattice row, g < @p groups,
/// added to @p fb: @p ub is u at the row's first cell's node 0, @p fb f there, @p rowE the cells'
/// moduli (0: inactive, no force), @p offset the dof offsets of a cell's 8 nodes from its node 0
/// (x fastest). Reads and writes the nodes of those cells only. @par Real-time  noexcept,
/// allocation-free.
void onePointRowAvx2(const double* __restrict ub, double* __restrict fb, const double* rowE,
                     int groups, const std::ptrdiff_t (&offset)[8],
                     const OnePointConstants& k) noexcept;
/// The same for four cells anywhere: node 0 of cell l at dof @p base[l] (a cell may repeat with
/// modulus 0 as padding), moduli @p cellE. @par Real-time  noexcept, allocation-free.
void onePointCellsAvx2(const double* __restrict u, double* __restrict f,
                       const std::ptrdiff_t (&base)[4], const double (&cellE)[4],
                       const std::ptrdiff_t (&offset)[8], const OnePointConstants& k) noexcept;
#endif

}  // namespace palp::fem::detail
