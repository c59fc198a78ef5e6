// PrimaryRegion: the primary's internal forces by P-node rows (docs/algorithms.md section 6,
// "Primary"): the lattice's unit stencil where a node's eight cells share one modulus, the
// node's cells' rows elsewhere.
#include "index_cast.h"
#include "palp/base/simd.h"
#include "regions/primary_region.h"

#if defined(__x86_64__) && (defined(__GNUC__) || defined(__clang__))
#include <immintrin.h>
#define PALP_STENCIL_AVX2 1
#endif

namespace palp::fem {

namespace {
#ifdef PALP_STENCIL_AVX2
/// The stencil rows of @p count nodes with AVX2 and FMA (the build targets baseline x86-64,
/// where Eigen's 4-vectors are two SSE2 halves with separate multiplies and adds): one 4-wide
/// FMA per stencil column, three accumulators (one per displacement component) so that the 27
/// points do not wait on one chain.
__attribute__((target("avx2,fma"))) void stencilRowsAvx2(const int* nodes, const double* modulus,
                                                         std::size_t count, const double* stencil,
                                                         const int* offsets, const double* operand,
                                                         double* fint) noexcept {
    for (std::size_t i = 0; i < count; ++i) {
        const int n = nodes[i];
        __m256d f0 = _mm256_setzero_pd(), f1 = _mm256_setzero_pd(), f2 = _mm256_setzero_pd();
        for (std::size_t o = 0; o < 27; ++o) {
            const double* u = operand + 3 * (n + offsets[o]);
            const double* s = stencil + 12 * o;
            f0 = _mm256_fmadd_pd(_mm256_loadu_pd(s), _mm256_broadcast_sd(u), f0);
            f1 = _mm256_fmadd_pd(_mm256_loadu_pd(s + 4), _mm256_broadcast_sd(u + 1), f1);
            f2 = _mm256_fmadd_pd(_mm256_loadu_pd(s + 8), _mm256_broadcast_sd(u + 2), f2);
        }
        alignas(32) double out[4];
        _mm256_store_pd(out, _mm256_add_pd(_mm256_add_pd(f0, f1), f2));
        const double e = modulus[i];
        fint[3 * n] = e * out[0];
        fint[3 * n + 1] = e * out[1];
        fint[3 * n + 2] = e * out[2];
    }
}

/// The rows of @p count other P nodes (surface, inclusions) with AVX2 and FMA: each of a node's
/// cells adds its modulus times the corner's three rows of K_e (@p cornerRows) times the cell's
/// 24 displacements.
__attribute__((target("avx2,fma"))) void cellRowsAvx2(
    const int* nodes, std::size_t count, const int* cellStart, const std::array<int, 2>* cells,
    const std::array<int, 8>* cellDofs, const double* cellE, const double* cornerRows,
    const double* operand, double* fint) noexcept {
    for (std::size_t i = 0; i < count; ++i) {
        __m256d f = _mm256_setzero_pd();
        for (int e = cellStart[i]; e < cellStart[i + 1]; ++e) {
            const std::array<int, 2>& cell = cells[e];
            const std::array<int, 8>& nd = cellDofs[cell[0]];
            const double* k = cornerRows + 96 * cell[1];
            __m256d g0 = _mm256_setzero_pd(), g1 = _mm256_setzero_pd(), g2 = _mm256_setzero_pd();
            for (std::size_t a = 0; a < 8; ++a) {
                const double* u = operand + nd[a];
                const double* c = k + 12 * a;
                g0 = _mm256_fmadd_pd(_mm256_loadu_pd(c), _mm256_broadcast_sd(u), g0);
                g1 = _mm256_fmadd_pd(_mm256_loadu_pd(c + 4), _mm256_broadcast_sd(u + 1), g1);
                g2 = _mm256_fmadd_pd(_mm256_loadu_pd(c + 8), _mm256_broadcast_sd(u + 2), g2);
            }
            const __m256d g = _mm256_add_pd(_mm256_add_pd(g0, g1), g2);
            f = _mm256_fmadd_pd(_mm256_set1_pd(cellE[cell[0]]), g, f);
        }
        alignas(32) double out[4];
        _mm256_store_pd(out, f);
        const int n = nodes[i];
        fint[3 * n] = out[0];
        fint[3 * n + 1] = out[1];
        fint[3 * n + 2] = out[2];
    }
}
#endif
}  // namespace

void PrimaryRegion::buildStencil() noexcept {
    // The lattice's assembled unit stiffness at a node inside eight cells: block (node, node +
    // offset) sums K_e's (a, b) blocks over the cells where the node is corner a and its
    // neighbour corner b (corner bits: x, y, z).
    const std::array<int, 3> nc = mSetup.model.mesh().nodeCounts();
    const Eigen::Map<const Eigen::Matrix<double, 24, 24>, Eigen::Aligned64> Ke(
        mSetup.model.unitStiffness());
#ifdef PALP_STENCIL_AVX2
    mStencilAvx2 = palp::avx2FmaEnabled();
#endif
    for (int a = 0; a < 8; ++a)
        for (int c = 0; c < 24; ++c)
            for (int r = 0; r < 4; ++r)
                mCornerRows[sz(96 * a + 4 * c + r)] = r < 3 ? Ke(3 * a + r, c) : 0.0;
    mStencil.fill(0.0);
    for (int q = 0; q < 27; ++q)
        mStencilOffset[sz(q)] = (q % 3 - 1) + nc[0] * ((q / 3) % 3 - 1 + nc[1] * (q / 9 - 1));
    for (int a = 0; a < 8; ++a)
        for (int b = 0; b < 8; ++b) {
            const int q = ((b & 1) - (a & 1) + 1) + 3 * (((b >> 1) & 1) - ((a >> 1) & 1) + 1) +
                          9 * (((b >> 2) & 1) - ((a >> 2) & 1) + 1);
            for (int r = 0; r < 3; ++r)
                for (int col = 0; col < 3; ++col)
                    mStencil[sz(12 * q + 4 * col + r)] += Ke(3 * a + r, 3 * b + col);
        }
}

void PrimaryRegion::internalForces(
    const Layout& L, const double* operand,
    const Eigen::Map<const Eigen::Matrix<double, 24, 24>, Eigen::Aligned64>& K) noexcept {
    // Rows of K u on P nodes (the only rows read): the unit stencil scaled by the modulus
    // where all eight cells are present with one modulus, the node's cells' rows elsewhere.
    bool done = false;
#ifdef PALP_STENCIL_AVX2
    if (mStencilAvx2) {
        stencilRowsAvx2(L.stencilNodes.data(), L.stencilE.data(), L.stencilNodes.size(),
                        mStencil.data(), mStencilOffset.data(), operand, mFInt.data());
        done = true;
    }
#endif
    for (std::size_t i = 0; !done && i < L.stencilNodes.size(); ++i) {
        const int n = L.stencilNodes[i];
        // Columns padded to 4 rows: whole packets.
        Eigen::Vector4d f = Eigen::Vector4d::Zero();
        for (std::size_t o = 0; o < kStencilPoints; ++o) {
            const double* u = operand + 3 * (n + mStencilOffset[o]);
            const double* s = mStencil.data() + 12 * o;
            f.noalias() += Eigen::Map<const Eigen::Vector4d, Eigen::Aligned16>(s) * u[0];
            f.noalias() += Eigen::Map<const Eigen::Vector4d, Eigen::Aligned16>(s + 4) * u[1];
            f.noalias() += Eigen::Map<const Eigen::Vector4d, Eigen::Aligned16>(s + 8) * u[2];
        }
        mFInt.segment<3>(3 * n) = L.stencilE[i] * f.head<3>();
    }
    cellRows(L.edgeNodes, L.edgeCellStart, L.edgeCells, L, operand, K);
}

void PrimaryRegion::cellRows(
    std::span<const int> nodes, std::span<const int> start,
    std::span<const std::array<int, 2>> cells, const Layout& L, const double* operand,
    const Eigen::Map<const Eigen::Matrix<double, 24, 24>, Eigen::Aligned64>& K) noexcept {
#ifdef PALP_STENCIL_AVX2
    if (mStencilAvx2) {
        cellRowsAvx2(nodes.data(), nodes.size(), start.data(), cells.data(), L.cellDofs.data(),
                     L.cellE.data(), mCornerRows.data(), operand, mFInt.data());
        return;
    }
#endif
    for (std::size_t i = 0; i < nodes.size(); ++i) {
        Eigen::Vector3d f = Eigen::Vector3d::Zero();
        for (int e = start[i]; e < start[i + 1]; ++e) {
            const std::array<int, 2>& cell = cells[sz(e)];
            const std::array<int, 8>& nd = L.cellDofs[sz(cell[0])];
            Eigen::Matrix<double, 24, 1> ue;
            for (int a = 0; a < 8; ++a) {
                for (int k = 0; k < 3; ++k) ue[3 * a + k] = operand[nd[sz(a)] + k];
            }
            f.noalias() += L.cellE[sz(cell[0])] * (K.middleRows<3>(3 * cell[1]) * ue);
        }
        mFInt.segment<3>(3 * nodes[i]) = f;
    }
}

}  // namespace palp::fem
