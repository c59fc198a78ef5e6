#pragma once
/// @file
/// InterpBasis: a capacitance layout's response basis `I_rows W(., J)` (issue 18) kept as its
/// two factors, the rows' trilinear interpolation (sparse, at most 8 entries a row) and the
/// zone block `W(T, J)` over the zone positions T those rows interpolate from. Multiplied out
/// it is |rows| x |J| dense (Gamma: up to 987 x 84 on the bone phantom's 2.5 mm body, ~660 KB
/// swept per product); factored it is |T| x |J| (T: the corners of the primary coarse cells
/// for Gamma, ~|J|) plus the interpolation: the servo's products read a tenth of the bytes.

#include <Eigen/Core>
#include <cstddef>
#include <vector>

#include "palp/base/simd.h"

#if defined(__x86_64__) && (defined(__GNUC__) || defined(__clang__))
#include <immintrin.h>
#define PALP_SWEEP_AVX2 1
#endif

namespace palp::fem {

/// Whether the CPU has AVX2 and FMA: dualProduct() then takes 4-wide FMAs (the build targets
/// baseline x86-64, where Eigen's products are SSE2 multiplies and adds; for one vector
/// Eigen's own product was as fast). The first call initialises a static: make it off the servo
/// (PrimaryRegion's constructor does).
inline bool sweepAvx2() noexcept {
#ifdef PALP_SWEEP_AVX2
    return palp::avx2FmaEnabled();
#else
    return false;
#endif
}

#ifdef PALP_SWEEP_AVX2
/// y_k = A x_k (k < K) for column-major A (rows x cols, leading dimension ld),
/// each column read once: 16-row strips whose accumulators stay in registers, then the rest.
template <std::size_t K>
__attribute__((target("avx2,fma"))) void sweepProductAvx2(const double* A, Eigen::Index rows,
                                                          Eigen::Index cols, Eigen::Index ld,
                                                          const double* const* x,
                                                          double* const* y) noexcept {
    Eigen::Index r = 0;
    for (; r + 16 <= rows; r += 16) {
        __m256d acc[K][4];
        for (std::size_t k = 0; k < K; ++k)
            for (std::size_t p = 0; p < 4; ++p) acc[k][p] = _mm256_setzero_pd();
        for (Eigen::Index j = 0; j < cols; ++j) {
            const double* c = A + j * ld + r;
            const __m256d c0 = _mm256_loadu_pd(c), c1 = _mm256_loadu_pd(c + 4),
                          c2 = _mm256_loadu_pd(c + 8), c3 = _mm256_loadu_pd(c + 12);
            for (std::size_t k = 0; k < K; ++k) {
                const __m256d a = _mm256_broadcast_sd(x[k] + j);
                acc[k][0] = _mm256_fmadd_pd(a, c0, acc[k][0]);
                acc[k][1] = _mm256_fmadd_pd(a, c1, acc[k][1]);
                acc[k][2] = _mm256_fmadd_pd(a, c2, acc[k][2]);
                acc[k][3] = _mm256_fmadd_pd(a, c3, acc[k][3]);
            }
        }
        for (std::size_t k = 0; k < K; ++k)
            for (std::size_t p = 0; p < 4; ++p) _mm256_storeu_pd(y[k] + r + 4 * p, acc[k][p]);
    }
    for (; r < rows; ++r) {
        double s[K] = {};
        for (Eigen::Index j = 0; j < cols; ++j)
            for (std::size_t k = 0; k < K; ++k) s[k] += A[j * ld + r] * x[k][j];
        for (std::size_t k = 0; k < K; ++k) y[k][r] = s[k];
    }
}
#endif

/// `B = S block`: S sparse (rows x |T|, CSR in start/col/weight), block dense |T| x |J|.
struct InterpBasis {
    Eigen::MatrixXd block;       ///< W(T, J), |T| x |J|
    std::vector<int> pos;        ///< T: zone position of each row of block
    std::vector<int> start{0};   ///< row r's entries: [start[r], start[r + 1])
    std::vector<int> col;        ///< entry -> row of block
    std::vector<double> weight;  ///< entry -> interpolation weight

    Eigen::Index rows() const noexcept { return static_cast<Eigen::Index>(start.size()) - 1; }
    Eigen::Index cols() const noexcept { return block.cols(); }
    /// Whether it holds a basis of @p rowCount rows and @p jCount columns.
    bool fits(Eigen::Index rowCount, Eigen::Index jCount) const noexcept {
        return rows() == rowCount && cols() == jCount && !start.empty();
    }
    void clear() {
        block.resize(0, 0);
        pos.clear();
        start.assign(1, 0);
        col.clear();
        weight.clear();
    }

    /// out = S y for y = block z (given): row r of out is its interpolation of y.
    void interpolate(const double* y, double* out) const noexcept {
        const Eigen::Index n = rows();
        for (Eigen::Index r = 0; r < n; ++r) {
            double s = 0.0;
            for (int e = start[static_cast<std::size_t>(r)];
                 e < start[static_cast<std::size_t>(r) + 1]; ++e)
                s += weight[static_cast<std::size_t>(e)] * y[col[static_cast<std::size_t>(e)]];
            out[r] = s;
        }
    }
    /// out = B z; @p y: work space of block.rows() values.
    void apply(Eigen::Ref<const Eigen::VectorXd> z, Eigen::Ref<Eigen::VectorXd> y,
               double* out) const noexcept {
        y.noalias() = block * z;
        interpolate(y.data(), out);
    }
};

/// y1 = A x1 and y2 = A x2 in one sweep over A's columns (each read once from memory).
inline void dualProduct(const Eigen::MatrixXd& A, Eigen::Ref<const Eigen::VectorXd> x1,
                        Eigen::Ref<const Eigen::VectorXd> x2, Eigen::Ref<Eigen::VectorXd> y1,
                        Eigen::Ref<Eigen::VectorXd> y2) noexcept {
#ifdef PALP_SWEEP_AVX2
    if (sweepAvx2()) {
        const double* xs[2] = {x1.data(), x2.data()};
        double* ys[2] = {y1.data(), y2.data()};
        sweepProductAvx2<2>(A.data(), A.rows(), A.cols(), A.rows(), xs, ys);
        return;
    }
#endif
    y1.setZero();
    y2.setZero();
    for (Eigen::Index j = 0; j < A.cols(); ++j) {
        const auto col = A.col(j);
        y1.noalias() += x1[j] * col;
        y2.noalias() += x2[j] * col;
    }
}

/// out1 = B z1 and out2 = B z2 for a factored basis B: each factor swept once;
/// @p y: work space of 2 |T| values.
inline void dualProduct(const InterpBasis& B, Eigen::Ref<const Eigen::VectorXd> z1,
                        Eigen::Ref<const Eigen::VectorXd> z2, Eigen::Ref<Eigen::VectorXd> y,
                        double* out1, double* out2) noexcept {
    const Eigen::Index t = B.block.rows();
    dualProduct(B.block, z1, z2, y.head(t), y.segment(t, t));
    const double* y1 = y.data();
    const double* y2 = y.data() + t;
    for (Eigen::Index r = 0; r < B.rows(); ++r) {
        double s1 = 0.0, s2 = 0.0;
        for (int e = B.start[static_cast<std::size_t>(r)];
             e < B.start[static_cast<std::size_t>(r) + 1]; ++e) {
            const double w = B.weight[static_cast<std::size_t>(e)];
            s1 += w * y1[B.col[static_cast<std::size_t>(e)]];
            s2 += w * y2[B.col[static_cast<std::size_t>(e)]];
        }
        out1[r] = s1;
        out2[r] = s2;
    }
}

}  // namespace palp::fem
