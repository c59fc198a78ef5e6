#include "palp/fem/tled.h"

#include <tbb/blocked_range.h>

#include <Eigen/Eigenvalues>
#include <algorithm>
#include <cmath>
#include <cstddef>
#include <limits>
#include <numbers>

#include "index_cast.h"
#include "palp/base/error.h"
#include "palp/base/parallel.h"
#include "palp/base/simd.h"
#include "palp/base/validate.h"
#include "palp/fem/hex_element.h"

#if defined(__x86_64__) && (defined(__GNUC__) || defined(__clang__))
#include <immintrin.h>
#define PALP_TLED_AVX2 1
#endif

namespace palp::fem {

namespace {

/// Corner signs of the 8 local nodes (hex_mesh.h's order, x fastest).
constexpr double kSign[8][3] = {{-1, -1, -1}, {1, -1, -1}, {-1, 1, -1}, {1, 1, -1},
                                {-1, -1, 1},  {1, -1, 1},  {-1, 1, 1},  {1, 1, 1}};

/// Flanagan-Belytschko hourglass base vectors of the cube, one per mode (yz, xz, xy, xyz sign
/// products), normalised to unit length (entries +-1 / sqrt(8)). On a cube they are orthogonal
/// to the constant and linear nodal fields, so they see neither rigid nor affine motion.
struct HourglassVectors {
    double g[4][8];
    constexpr HourglassVectors() : g{} {
        const double s = 0.35355339059327373;  // 1 / sqrt(8)
        for (int a = 0; a < 8; ++a) {
            g[0][a] = s * kSign[a][1] * kSign[a][2];
            g[1][a] = s * kSign[a][0] * kSign[a][2];
            g[2][a] = s * kSign[a][0] * kSign[a][1];
            g[3][a] = s * kSign[a][0] * kSign[a][1] * kSign[a][2];
        }
    }
};
constexpr HourglassVectors kHourglass{};

/// Energy density and first Piola stress of the neo-Hookean law (mu, bulk) at F (row-major
/// 3x3): `P = mu J^(-2/3) F + (K (J - 1) - mu J^(-2/3) I1 / (3 J)) cof F`. Returns W.
[[gnu::always_inline]] inline double piola(const double (&f)[3][3], double mu, double bulk,
                                           double (&p)[3][3]) noexcept {
    double c[3][3];
    c[0][0] = f[1][1] * f[2][2] - f[1][2] * f[2][1];
    c[0][1] = f[1][2] * f[2][0] - f[1][0] * f[2][2];
    c[0][2] = f[1][0] * f[2][1] - f[1][1] * f[2][0];
    c[1][0] = f[0][2] * f[2][1] - f[0][1] * f[2][2];
    c[1][1] = f[0][0] * f[2][2] - f[0][2] * f[2][0];
    c[1][2] = f[0][1] * f[2][0] - f[0][0] * f[2][1];
    c[2][0] = f[0][1] * f[1][2] - f[0][2] * f[1][1];
    c[2][1] = f[0][2] * f[1][0] - f[0][0] * f[1][2];
    c[2][2] = f[0][0] * f[1][1] - f[0][1] * f[1][0];
    const double j = f[0][0] * c[0][0] + f[0][1] * c[0][1] + f[0][2] * c[0][2];
    double i1 = 0.0;
    for (int r = 0; r < 3; ++r) {
        for (int s = 0; s < 3; ++s) i1 += f[r][s] * f[r][s];
    }
    const double j23 = 1.0 / std::cbrt(j * j);  // J^(-2/3)
    const double a = mu * j23;
    const double b = bulk * (j - 1.0) - a * i1 / (3.0 * j);
    for (int r = 0; r < 3; ++r) {
        for (int s = 0; s < 3; ++s) p[r][s] = a * f[r][s] + b * c[r][s];
    }
    return 0.5 * mu * (j23 * i1 - 3.0) + 0.5 * bulk * (j - 1.0) * (j - 1.0);
}

/// Local dof offset of node a of a cell whose node 0 is at dof 0, for lattice rows of
/// @p dy dofs and planes of @p dz dofs.
struct NodeOffsets {
    std::ptrdiff_t o[8];
    NodeOffsets(std::ptrdiff_t dy, std::ptrdiff_t dz)
        : o{0, 3, dy, dy + 3, dz, dz + 3, dy + dz, dy + dz + 3} {}
};

/// Largest and smallest eigenvalue of the symmetric 3x3 @p m (closed form, Smith 1961).
void symmetricExtremes(const double (&m)[3][3], double& lo, double& hi) noexcept {
    const double p1 = m[0][1] * m[0][1] + m[0][2] * m[0][2] + m[1][2] * m[1][2];
    const double q = (m[0][0] + m[1][1] + m[2][2]) / 3.0;
    const double d0 = m[0][0] - q, d1 = m[1][1] - q, d2 = m[2][2] - q;
    const double p2 = d0 * d0 + d1 * d1 + d2 * d2 + 2.0 * p1;
    if (p2 <= 1e-30 * q * q) {
        lo = hi = q;
        return;
    }
    const double p = std::sqrt(p2 / 6.0);
    const double b00 = d0 / p, b11 = d1 / p, b22 = d2 / p;
    const double b01 = m[0][1] / p, b02 = m[0][2] / p, b12 = m[1][2] / p;
    const double detB = b00 * (b11 * b22 - b12 * b12) - b01 * (b01 * b22 - b12 * b02) +
                        b02 * (b01 * b12 - b11 * b02);
    const double r = std::clamp(0.5 * detB, -1.0, 1.0);
    const double phi = std::acos(r) / 3.0;
    hi = q + 2.0 * p * std::cos(phi);
    lo = q + 2.0 * p * std::cos(phi + 2.0 * std::numbers::pi / 3.0);
}

/// Upper bound of the neo-Hookean acoustic tensor's largest eigenvalue at F (the second
/// derivative of W along F + t m N^T over unit m, N): with a = N . F^-1 m (|a| <= 1 / s_min)
/// and |m . F N| <= s_max it is at most
/// `mu / 2 J^(-2/3) (10/9 I1 a^2 + 8/3 |a| s_max + 2) + K J^2 a^2`.
double acousticBound(const double (&f)[3][3], double mu, double bulk) noexcept {
    double cg[3][3];
    for (int r = 0; r < 3; ++r) {
        for (int s = 0; s < 3; ++s)
            cg[r][s] = f[0][r] * f[0][s] + f[1][r] * f[1][s] + f[2][r] * f[2][s];
    }
    double lo = 0.0, hi = 0.0;
    symmetricExtremes(cg, lo, hi);
    const double j = f[0][0] * (f[1][1] * f[2][2] - f[1][2] * f[2][1]) -
                     f[0][1] * (f[1][0] * f[2][2] - f[1][2] * f[2][0]) +
                     f[0][2] * (f[1][0] * f[2][1] - f[1][1] * f[2][0]);
    if (!(lo > 0.0) || !(j > 0.0)) return std::numeric_limits<double>::infinity();
    const double i1 = cg[0][0] + cg[1][1] + cg[2][2];
    const double a2 = 1.0 / lo;
    return 0.5 * mu / std::cbrt(j * j) *
               (10.0 / 9.0 * i1 * a2 + 8.0 / 3.0 * std::sqrt(hi * a2) + 2.0) +
           bulk * j * j * a2;
}

/// The cell loop shared by the force, energy and frequency passes: calls
/// visit(E, dofOffset of node 0) for each active cell of slabs [kBegin, kEnd).
template <class Visit>
[[gnu::always_inline]] inline void forCells(const HexMesh& mesh, int kBegin, int kEnd,
                                            Visit&& visit) noexcept {
    const auto& nc = mesh.nodeCounts();
    const int cx = nc[0] - 1, cy = nc[1] - 1;
    const double* cellE = mesh.cellYoungs().data();
    for (int k = kBegin; k < kEnd; ++k) {
        for (int j = 0; j < cy; ++j) {
            const double* rowE = cellE + static_cast<std::ptrdiff_t>(cx) * (j + cy * k);
            const std::ptrdiff_t rowBase = 3 * static_cast<std::ptrdiff_t>(nc[0]) * (j + nc[1] * k);
            for (int i = 0; i < cx; ++i) {
                if (rowE[i] == 0.0) continue;
                visit(rowE[i], rowBase + 3 * i);
            }
        }
    }
}

/// F = I + (sum_a u_a grad_a^T) / h at one point, grad_a = h dN_a/dX there (dimensionless).
[[gnu::always_inline]] inline void deformationGradient(const double* __restrict u,
                                                       const NodeOffsets& off,
                                                       const double (*grad)[3], double invH,
                                                       double (&f)[3][3]) noexcept {
    double d[3][3] = {};
    for (int a = 0; a < 8; ++a) {
        const double* ua = u + off.o[a];
        for (int i = 0; i < 3; ++i) {
            for (int jj = 0; jj < 3; ++jj) d[i][jj] += ua[i] * grad[a][jj];
        }
    }
    for (int i = 0; i < 3; ++i) {
        for (int jj = 0; jj < 3; ++jj) f[i][jj] = (i == jj ? 1.0 : 0.0) + d[i][jj] * invH;
    }
}

/// The centre gradients h dN_a/dX = s_a / 4.
struct CentreGradients {
    double g[8][3];
    constexpr CentreGradients() : g{} {
        for (int a = 0; a < 8; ++a) {
            for (int jj = 0; jj < 3; ++jj) g[a][jj] = 0.25 * kSign[a][jj];
        }
    }
};
constexpr CentreGradients kCentre{};

#ifdef PALP_TLED_AVX2
// The one-point element four cells at a time (docs/algorithms.md, "Large strain: TLED", "The
// one-point kernel"): lanes are four neighbouring cells of a lattice row. The element's nodal
// values and forces live on the 8-point sign basis of the cube (1, x, y, z, yz, xz, xy, xyz): a
// Walsh-Hadamard butterfly of 23 additions per displacement component gives F's columns
// (x, y, z) and the four hourglass amplitudes (yz, xz, xy, xyz) at once, and its transpose
// turns the stress and hourglass coefficients back into the 8 nodal forces.

/// Four nodes' xyz (12 consecutive doubles at @p p) as their x, y and z components.
__attribute__((target("avx2,fma"))) inline void loadNodes4(const double* p, __m256d& x, __m256d& y,
                                                           __m256d& z) noexcept {
    const __m256d r0 = _mm256_loadu_pd(p), r1 = _mm256_loadu_pd(p + 4), r2 = _mm256_loadu_pd(p + 8);
    // r0 = x0 y0 z0 x1, r1 = y1 z1 x2 y2, r2 = z2 x3 y3 z3.
    x = _mm256_permute4x64_pd(_mm256_blend_pd(_mm256_blend_pd(r0, r1, 0b0100), r2, 0b0010),
                              _MM_SHUFFLE(1, 2, 3, 0));
    y = _mm256_permute4x64_pd(_mm256_blend_pd(_mm256_blend_pd(r0, r1, 0b1001), r2, 0b0100),
                              _MM_SHUFFLE(2, 3, 0, 1));
    z = _mm256_permute4x64_pd(_mm256_blend_pd(_mm256_blend_pd(r0, r1, 0b0010), r2, 0b1001),
                              _MM_SHUFFLE(3, 0, 1, 2));
}

/// Adds four nodes' forces, given as x, y and z components, to the 12 doubles at @p p.
__attribute__((target("avx2,fma"))) inline void addNodes4(double* p, __m256d x, __m256d y,
                                                          __m256d z) noexcept {
    const __m256d xp = _mm256_permute4x64_pd(x, _MM_SHUFFLE(1, 2, 3, 0));  // x0 x3 x2 x1
    const __m256d yp = _mm256_permute4x64_pd(y, _MM_SHUFFLE(2, 3, 0, 1));  // y1 y0 y3 y2
    const __m256d zp = _mm256_permute4x64_pd(z, _MM_SHUFFLE(3, 0, 1, 2));  // z2 z1 z0 z3
    const __m256d r0 = _mm256_blend_pd(_mm256_blend_pd(xp, yp, 0b0010), zp, 0b0100);
    const __m256d r1 = _mm256_blend_pd(_mm256_blend_pd(yp, zp, 0b0010), xp, 0b0100);
    const __m256d r2 = _mm256_blend_pd(_mm256_blend_pd(zp, xp, 0b0010), yp, 0b0100);
    _mm256_storeu_pd(p, _mm256_add_pd(_mm256_loadu_pd(p), r0));
    _mm256_storeu_pd(p + 4, _mm256_add_pd(_mm256_loadu_pd(p + 4), r1));
    _mm256_storeu_pd(p + 8, _mm256_add_pd(_mm256_loadu_pd(p + 8), r2));
}

/// One displacement component's sign-basis coefficients: sums of s_a v_a over the 8 nodes for
/// the linear signs (F's columns) and the hourglass products.
struct SignCoefficients {
    __m256d x, y, z, yz, xz, xy, xyz;
};

/// The butterfly: @p v holds the component at the 8 nodes (x fastest).
__attribute__((target("avx2,fma"))) inline SignCoefficients forwardSigns(
    const __m256d (&v)[8]) noexcept {
    const __m256d p0 = _mm256_add_pd(v[0], v[1]), m0 = _mm256_sub_pd(v[1], v[0]);
    const __m256d p1 = _mm256_add_pd(v[2], v[3]), m1 = _mm256_sub_pd(v[3], v[2]);
    const __m256d p2 = _mm256_add_pd(v[4], v[5]), m2 = _mm256_sub_pd(v[5], v[4]);
    const __m256d p3 = _mm256_add_pd(v[6], v[7]), m3 = _mm256_sub_pd(v[7], v[6]);
    const __m256d pp0 = _mm256_add_pd(p0, p1), pm0 = _mm256_sub_pd(p1, p0);
    const __m256d pp1 = _mm256_add_pd(p2, p3), pm1 = _mm256_sub_pd(p3, p2);
    const __m256d mp0 = _mm256_add_pd(m0, m1), mm0 = _mm256_sub_pd(m1, m0);
    const __m256d mp1 = _mm256_add_pd(m2, m3), mm1 = _mm256_sub_pd(m3, m2);
    return {_mm256_add_pd(mp0, mp1), _mm256_add_pd(pm0, pm1), _mm256_sub_pd(pp1, pp0),
            _mm256_sub_pd(pm1, pm0), _mm256_sub_pd(mp1, mp0), _mm256_add_pd(mm0, mm1),
            _mm256_sub_pd(mm1, mm0)};
}

/// The transpose of forwardSigns(): the nodal values sum_b c_b s_b(a) of coefficients @p c.
__attribute__((target("avx2,fma"))) inline void inverseSigns(const SignCoefficients& c,
                                                             __m256d (&v)[8]) noexcept {
    const __m256d pm0 = _mm256_sub_pd(c.y, c.yz), pm1 = _mm256_add_pd(c.y, c.yz);
    const __m256d mp0 = _mm256_sub_pd(c.x, c.xz), mp1 = _mm256_add_pd(c.x, c.xz);
    const __m256d mm0 = _mm256_sub_pd(c.xy, c.xyz), mm1 = _mm256_add_pd(c.xy, c.xyz);
    // pp0 = -z, pp1 = z.
    const __m256d p0 = _mm256_sub_pd(_mm256_setzero_pd(), _mm256_add_pd(c.z, pm0));
    const __m256d p1 = _mm256_sub_pd(pm0, c.z);
    const __m256d p2 = _mm256_sub_pd(c.z, pm1), p3 = _mm256_add_pd(c.z, pm1);
    const __m256d m0 = _mm256_sub_pd(mp0, mm0), m1 = _mm256_add_pd(mp0, mm0);
    const __m256d m2 = _mm256_sub_pd(mp1, mm1), m3 = _mm256_add_pd(mp1, mm1);
    v[0] = _mm256_sub_pd(p0, m0);
    v[1] = _mm256_add_pd(p0, m0);
    v[2] = _mm256_sub_pd(p1, m1);
    v[3] = _mm256_add_pd(p1, m1);
    v[4] = _mm256_sub_pd(p2, m2);
    v[5] = _mm256_add_pd(p2, m2);
    v[6] = _mm256_sub_pd(p3, m3);
    v[7] = _mm256_add_pd(p3, m3);
}

/// x^(-1/3) of positive @p x: a first guess from the exponent bits, then four Newton steps
/// y <- y (4 - x y^3) / 3 (the relative error e becomes 2 e^2: about 6e-2, 7e-3, 1e-4, 2e-8,
/// 1e-15).
__attribute__((target("avx2,fma"))) inline __m256d inverseCubeRoot(__m256d x) noexcept {
    // The high 32 bits of x as a number, divided by 3 and taken from the magic constant's high
    // word (the exponent's third, with the mantissa's linear approximation).
    const __m256i hi = _mm256_srli_epi64(_mm256_castpd_si256(x), 32);
    const __m128i packed = _mm256_castsi256_si128(
        _mm256_permutevar8x32_epi32(hi, _mm256_setr_epi32(0, 2, 4, 6, 0, 2, 4, 6)));
    const __m256d guessHi = _mm256_fnmadd_pd(_mm256_cvtepi32_pd(packed), _mm256_set1_pd(1.0 / 3.0),
                                             _mm256_set1_pd(1430187263.0));  // 0x553ef0ff
    __m256d y = _mm256_castsi256_pd(
        _mm256_slli_epi64(_mm256_cvtepu32_epi64(_mm256_cvttpd_epi32(guessHi)), 32));
    const __m256d third = _mm256_mul_pd(x, _mm256_set1_pd(1.0 / 3.0));
    const __m256d fourThirds = _mm256_set1_pd(4.0 / 3.0);
    for (int i = 0; i < 4; ++i) {
        const __m256d y3 = _mm256_mul_pd(_mm256_mul_pd(y, y), y);
        y = _mm256_mul_pd(y, _mm256_fnmadd_pd(third, y3, fourThirds));
    }
    return y;
}

/// a^2 + b^2 + c^2.
__attribute__((target("avx2,fma"))) inline __m256d sumOfSquares(__m256d a, __m256d b,
                                                                __m256d c) noexcept {
    return _mm256_fmadd_pd(c, c, _mm256_fmadd_pd(b, b, _mm256_mul_pd(a, a)));
}

/// Row i of area P = area (a F + b cof F) into @p out (aa = area a, ba = area b).
__attribute__((target("avx2,fma"))) inline void piolaRow(__m256d aa, __m256d ba, __m256d f0,
                                                         __m256d f1, __m256d f2, __m256d k0,
                                                         __m256d k1, __m256d k2,
                                                         __m256d (&out)[3]) noexcept {
    out[0] = _mm256_fmadd_pd(aa, f0, _mm256_mul_pd(ba, k0));
    out[1] = _mm256_fmadd_pd(aa, f1, _mm256_mul_pd(ba, k1));
    out[2] = _mm256_fmadd_pd(aa, f2, _mm256_mul_pd(ba, k2));
}

/// One component's force coefficients: the stress row @p p on the linear signs, the hourglass
/// springs (@p hg = E kappa (K + 4/3 mu) h / 8 per lane) times the amplitudes of @p c.
__attribute__((target("avx2,fma"))) inline SignCoefficients nodalCoefficients(
    const SignCoefficients& c, __m256d hg, const __m256d (&p)[3]) noexcept {
    return {p[0],
            p[1],
            p[2],
            _mm256_mul_pd(hg, c.yz),
            _mm256_mul_pd(hg, c.xz),
            _mm256_mul_pd(hg, c.xy),
            _mm256_mul_pd(hg, c.xyz)};
}

/// The one-point element's forces of cells 4 g .. 4 g + 3 of a lattice row, g < @p groups, added
/// to @p f: @p ub is u at the row's first node, @p fb f there, @p rowE the cells' moduli (0:
/// inactive, no force). @p gradScale = 1 / (4 h), @p area = h^2 / 4, @p mu1 and @p bulk1 the law
/// for E = 1, @p hourglass8 the hourglass spring for E = 1 over 8.
__attribute__((target("avx2,fma"))) void onePointRowAvx2(const double* __restrict ub,
                                                         double* __restrict fb, const double* rowE,
                                                         int groups, const NodeOffsets& off,
                                                         double gradScale, double area, double mu1,
                                                         double bulk1, double hourglass8) noexcept {
    const __m256d one = _mm256_set1_pd(1.0), zero = _mm256_setzero_pd();
    for (int g = 0; g < groups; ++g) {
        const __m256d e = _mm256_loadu_pd(rowE + 4 * g);
        const __m256d active = _mm256_cmp_pd(e, zero, _CMP_NEQ_OQ);
        if (_mm256_movemask_pd(active) == 0) continue;
        const double* u = ub + 12 * static_cast<std::ptrdiff_t>(g);
        __m256d v[3][8];
        for (int a = 0; a < 8; ++a) loadNodes4(u + off.o[a], v[0][a], v[1][a], v[2][a]);
        const SignCoefficients c0 = forwardSigns(v[0]), c1 = forwardSigns(v[1]),
                               c2 = forwardSigns(v[2]);
        // F = I + grad u, grad u's row i from component i's x, y, z coefficients.
        const __m256d s = _mm256_set1_pd(gradScale);
        const __m256d f00 = _mm256_fmadd_pd(c0.x, s, one), f01 = _mm256_mul_pd(c0.y, s),
                      f02 = _mm256_mul_pd(c0.z, s);
        const __m256d f10 = _mm256_mul_pd(c1.x, s), f11 = _mm256_fmadd_pd(c1.y, s, one),
                      f12 = _mm256_mul_pd(c1.z, s);
        const __m256d f20 = _mm256_mul_pd(c2.x, s), f21 = _mm256_mul_pd(c2.y, s),
                      f22 = _mm256_fmadd_pd(c2.z, s, one);
        // cof F and J, as piola() computes them.
        const __m256d k00 = _mm256_fmsub_pd(f11, f22, _mm256_mul_pd(f12, f21));
        const __m256d k01 = _mm256_fmsub_pd(f12, f20, _mm256_mul_pd(f10, f22));
        const __m256d k02 = _mm256_fmsub_pd(f10, f21, _mm256_mul_pd(f11, f20));
        const __m256d k10 = _mm256_fmsub_pd(f02, f21, _mm256_mul_pd(f01, f22));
        const __m256d k11 = _mm256_fmsub_pd(f00, f22, _mm256_mul_pd(f02, f20));
        const __m256d k12 = _mm256_fmsub_pd(f01, f20, _mm256_mul_pd(f00, f21));
        const __m256d k20 = _mm256_fmsub_pd(f01, f12, _mm256_mul_pd(f02, f11));
        const __m256d k21 = _mm256_fmsub_pd(f02, f10, _mm256_mul_pd(f00, f12));
        const __m256d k22 = _mm256_fmsub_pd(f00, f11, _mm256_mul_pd(f01, f10));
        const __m256d jRaw =
            _mm256_fmadd_pd(f02, k02, _mm256_fmadd_pd(f01, k01, _mm256_mul_pd(f00, k00)));
        // Inactive lanes take J = 1 (no infinity or NaN) and lose their force below.
        const __m256d j = _mm256_blendv_pd(one, jRaw, active);
        const __m256d i1 =
            _mm256_add_pd(_mm256_add_pd(sumOfSquares(f00, f01, f02), sumOfSquares(f10, f11, f12)),
                          sumOfSquares(f20, f21, f22));
        const __m256d j23 = inverseCubeRoot(_mm256_mul_pd(j, j));
        const __m256d aCoef = _mm256_mul_pd(_mm256_mul_pd(e, _mm256_set1_pd(mu1)), j23);
        const __m256d bCoef = _mm256_fmsub_pd(
            _mm256_mul_pd(e, _mm256_set1_pd(bulk1)), _mm256_sub_pd(j, one),
            _mm256_div_pd(_mm256_mul_pd(aCoef, i1), _mm256_mul_pd(_mm256_set1_pd(3.0), j)));
        // area P = area (a F + b cof F), masked to the active lanes.
        const __m256d aa = _mm256_and_pd(_mm256_mul_pd(aCoef, _mm256_set1_pd(area)), active);
        const __m256d ba = _mm256_and_pd(_mm256_mul_pd(bCoef, _mm256_set1_pd(area)), active);
        const __m256d hg = _mm256_and_pd(_mm256_mul_pd(e, _mm256_set1_pd(hourglass8)), active);
        __m256d p[3][3];
        piolaRow(aa, ba, f00, f01, f02, k00, k01, k02, p[0]);
        piolaRow(aa, ba, f10, f11, f12, k10, k11, k12, p[1]);
        piolaRow(aa, ba, f20, f21, f22, k20, k21, k22, p[2]);
        inverseSigns(nodalCoefficients(c0, hg, p[0]), v[0]);
        inverseSigns(nodalCoefficients(c1, hg, p[1]), v[1]);
        inverseSigns(nodalCoefficients(c2, hg, p[2]), v[2]);
        double* fg = fb + 12 * static_cast<std::ptrdiff_t>(g);
        for (int a = 0; a < 8; ++a) addNodes4(fg + off.o[a], v[0][a], v[1][a], v[2][a]);
    }
}
#endif

}  // namespace

NeoHookean NeoHookean::fromYoungs(double e, double nu) noexcept {
    return {e / (2.0 * (1.0 + nu)), e / (3.0 * (1.0 - 2.0 * nu))};
}

double NeoHookean::energy(const Eigen::Matrix3d& fm) const noexcept {
    double f[3][3], p[3][3];
    for (int r = 0; r < 3; ++r) {
        for (int s = 0; s < 3; ++s) f[r][s] = fm(r, s);
    }
    return piola(f, mu, bulk, p);
}

Eigen::Matrix3d NeoHookean::firstPiola(const Eigen::Matrix3d& fm) const noexcept {
    double f[3][3], p[3][3];
    for (int r = 0; r < 3; ++r) {
        for (int s = 0; s < 3; ++s) f[r][s] = fm(r, s);
    }
    piola(f, mu, bulk, p);
    Eigen::Matrix3d out;
    for (int r = 0; r < 3; ++r) {
        for (int s = 0; s < 3; ++s) out(r, s) = p[r][s];
    }
    return out;
}

Eigen::Matrix3d NeoHookean::secondPiola(const Eigen::Matrix3d& f) const noexcept {
    const Eigen::Matrix3d c = f.transpose() * f;
    const Eigen::Matrix3d cInv = c.inverse();
    const double j = f.determinant();
    const double j23 = 1.0 / std::cbrt(j * j);
    return mu * j23 * (Eigen::Matrix3d::Identity() - c.trace() / 3.0 * cInv) +
           bulk * j * (j - 1.0) * cInv;
}

TledForces::TledForces(const FemModel& model, const TledOptions& options)
    : mModel(model), mOptions(options) {
    requireInRange("TLED hourglassKappa", options.hourglassKappa, 0.0, 1.0);
#ifdef PALP_TLED_AVX2
    mAvx2 = palp::avx2FmaEnabled();
#endif
    const ElasticMaterial& m = model.material();
    mUnitLaw = NeoHookean::fromYoungs(1.0, m.poissonRatio);
    const double g = 1.0 / std::sqrt(3.0);
    for (int p = 0; p < 8; ++p) {
        const double xi[3] = {(p & 1) ? g : -g, (p & 2) ? g : -g, (p & 4) ? g : -g};
        for (int a = 0; a < 8; ++a) {
            for (int jj = 0; jj < 3; ++jj) {
                // h dN_a/dX_J = (2 / 8) s_J prod_{K != J} (1 + s_K xi_K).
                double v = 0.25 * kSign[a][jj];
                for (int kk = 0; kk < 3; ++kk) {
                    if (kk != jj) v *= 1.0 + kSign[a][kk] * xi[kk];
                }
                mGaussGrad[p][a][jj] = v;
            }
        }
    }
    const HexMesh& mesh = model.mesh();
    for (int c = 0; c < mesh.cellCount(); ++c) {
        if (mesh.cellActive(c)) mCellEMax = std::max(mCellEMax, mesh.cellYoungs()[sz(c)]);
    }
    if (options.integration == TledIntegration::gauss2x2x2) {
        mOmegaRest = model.maxFrequencyBound();
        return;
    }
    // The undeformed one-point element's stiffness for E = 1: V B0^T C B0 plus the hourglass
    // springs; its largest eigenvalue over the node mass gives the rest frequency bound.
    const double h = mesh.edge();
    const Eigen::Matrix<double, 6, 24> b0 = hexStrainDisplacement(h, 0.0, 0.0, 0.0);
    Eigen::Matrix<double, 24, 24> ke =
        h * h * h * (b0.transpose() * elasticityMatrix(1.0, m.poissonRatio) * b0);
    const double kHg = hourglassStiffness(h);
    for (int al = 0; al < 4; ++al) {
        for (int a = 0; a < 8; ++a) {
            for (int b = 0; b < 8; ++b) {
                for (int i = 0; i < 3; ++i)
                    ke(3 * a + i, 3 * b + i) += kHg * kHourglass.g[al][a] * kHourglass.g[al][b];
            }
        }
    }
    const Eigen::SelfAdjointEigenSolver<Eigen::Matrix<double, 24, 24>> eig(
        0.5 * (ke + ke.transpose()), Eigen::EigenvaluesOnly);
    const double nodeMass = m.density * h * h * h / 8.0;
    mOmegaRest = std::sqrt(mCellEMax * eig.eigenvalues().maxCoeff() / nodeMass);
}

double TledForces::hourglassStiffness(double edge) const noexcept {
    return mOptions.hourglassKappa * (mUnitLaw.bulk + 4.0 / 3.0 * mUnitLaw.mu) * edge;
}

void TledForces::addInternalForcesSlab(const double* __restrict u, double* __restrict f, int kBegin,
                                       int kEnd) const noexcept {
    const HexMesh& mesh = mModel.mesh();
    const double h = mesh.edge(), invH = 1.0 / h;
    const std::ptrdiff_t dy = 3 * static_cast<std::ptrdiff_t>(mesh.nodeCounts()[0]);
    const NodeOffsets off(dy, dy * mesh.nodeCounts()[1]);
    const double mu1 = mUnitLaw.mu, k1 = mUnitLaw.bulk;
    if (mOptions.integration == TledIntegration::onePointHourglass) {
        const double area = 0.25 * h * h;  // V |dN/dX| = h^3 / (4 h)
        const double kHg = hourglassStiffness(h);
        const auto cell = [&](double e, std::ptrdiff_t base) {
            const double* ue = u + base;
            double fm[3][3], p[3][3];
            deformationGradient(ue, off, kCentre.g, invH, fm);
            piola(fm, e * mu1, e * k1, p);
            // Hourglass amplitudes q = G^T u per mode and component.
            double q[4][3] = {};
            for (int a = 0; a < 8; ++a) {
                const double* ua = ue + off.o[a];
                for (int al = 0; al < 4; ++al) {
                    for (int i = 0; i < 3; ++i) q[al][i] += kHourglass.g[al][a] * ua[i];
                }
            }
            const double ke = e * kHg;
            for (int a = 0; a < 8; ++a) {
                double* fa = f + base + off.o[a];
                for (int i = 0; i < 3; ++i) {
                    double v = 0.0;
                    for (int jj = 0; jj < 3; ++jj) v += p[i][jj] * kSign[a][jj];
                    double hg = 0.0;
                    for (int al = 0; al < 4; ++al) hg += kHourglass.g[al][a] * q[al][i];
                    fa[i] += area * v + ke * hg;
                }
            }
        };
#ifdef PALP_TLED_AVX2
        if (mAvx2) {
            // Four cells of a row at a time, the row's last cx % 4 cells one by one.
            const auto& nc = mesh.nodeCounts();
            const int cx = nc[0] - 1, cy = nc[1] - 1, groups = cx / 4;
            const double* cellE = mesh.cellYoungs().data();
            for (int k = kBegin; k < kEnd; ++k) {
                for (int j = 0; j < cy; ++j) {
                    const double* rowE = cellE + static_cast<std::ptrdiff_t>(cx) * (j + cy * k);
                    const std::ptrdiff_t rowBase =
                        3 * static_cast<std::ptrdiff_t>(nc[0]) * (j + nc[1] * k);
                    onePointRowAvx2(u + rowBase, f + rowBase, rowE, groups, off, 0.25 * invH, area,
                                    mu1, k1, kHg / 8.0);
                    for (int i = 4 * groups; i < cx; ++i) {
                        if (rowE[i] != 0.0) cell(rowE[i], rowBase + 3 * i);
                    }
                }
            }
            return;
        }
#endif
        forCells(mesh, kBegin, kEnd, cell);
        return;
    }
    const double w = 0.125 * h * h;  // (h^3 / 8) / h: Gauss weight times dN/dX's 1 / h
    forCells(mesh, kBegin, kEnd, [&](double e, std::ptrdiff_t base) {
        const double* ue = u + base;
        double fe[8][3] = {};
        for (int gp = 0; gp < 8; ++gp) {
            double fm[3][3], p[3][3];
            deformationGradient(ue, off, mGaussGrad[gp], invH, fm);
            piola(fm, e * mu1, e * k1, p);
            for (int a = 0; a < 8; ++a) {
                for (int i = 0; i < 3; ++i) {
                    fe[a][i] += p[i][0] * mGaussGrad[gp][a][0] + p[i][1] * mGaussGrad[gp][a][1] +
                                p[i][2] * mGaussGrad[gp][a][2];
                }
            }
        }
        for (int a = 0; a < 8; ++a) {
            double* fa = f + base + off.o[a];
            for (int i = 0; i < 3; ++i) fa[i] += w * fe[a][i];
        }
    });
}

void TledForces::addInternalForces(const double* u, double* f) const noexcept {
    addInternalForcesSlab(u, f, 0, mModel.mesh().nodeCounts()[2] - 1);
}

void TledForces::internalForcesParallel(const double* u, double* f) const {
    const int cz = mModel.mesh().nodeCounts()[2] - 1;
    std::fill(f, f + mModel.dofCount(), 0.0);
    for (int parity = 0; parity < 2; ++parity) {
        const int slabs = (cz - parity + 1) / 2;
        parallelFor(tbb::blocked_range<int>(0, slabs), [&](const tbb::blocked_range<int>& r) {
            for (int s = r.begin(); s != r.end(); ++s) {
                const int k = 2 * s + parity;
                addInternalForcesSlab(u, f, k, k + 1);
            }
        });
    }
}

double TledForces::strainEnergy(const double* u) const noexcept {
    const HexMesh& mesh = mModel.mesh();
    const double h = mesh.edge(), invH = 1.0 / h, volume = h * h * h;
    const std::ptrdiff_t dy = 3 * static_cast<std::ptrdiff_t>(mesh.nodeCounts()[0]);
    const NodeOffsets off(dy, dy * mesh.nodeCounts()[1]);
    const bool onePoint = mOptions.integration == TledIntegration::onePointHourglass;
    const double kHg = hourglassStiffness(h);
    double total = 0.0;
    forCells(mesh, 0, mesh.nodeCounts()[2] - 1, [&](double e, std::ptrdiff_t base) {
        const double* ue = u + base;
        double fm[3][3], p[3][3];
        if (onePoint) {
            deformationGradient(ue, off, kCentre.g, invH, fm);
            total += volume * piola(fm, e * mUnitLaw.mu, e * mUnitLaw.bulk, p);
            for (int al = 0; al < 4; ++al) {
                for (int i = 0; i < 3; ++i) {
                    double q = 0.0;
                    for (int a = 0; a < 8; ++a) q += kHourglass.g[al][a] * ue[off.o[a] + i];
                    total += 0.5 * e * kHg * q * q;
                }
            }
            return;
        }
        for (int gp = 0; gp < 8; ++gp) {
            deformationGradient(ue, off, mGaussGrad[gp], invH, fm);
            total += 0.125 * volume * piola(fm, e * mUnitLaw.mu, e * mUnitLaw.bulk, p);
        }
    });
    return total;
}

double TledForces::frequencyBound(const double* u) const noexcept {
    const HexMesh& mesh = mModel.mesh();
    const double invH = 1.0 / mesh.edge();
    const std::ptrdiff_t dy = 3 * static_cast<std::ptrdiff_t>(mesh.nodeCounts()[0]);
    const NodeOffsets off(dy, dy * mesh.nodeCounts()[1]);
    const double mu = mUnitLaw.mu, bulk = mUnitLaw.bulk;
    const double identity[3][3] = {{1, 0, 0}, {0, 1, 0}, {0, 0, 1}};
    const double rest = acousticBound(identity, mu, bulk);
    double worst = 0.0;
    forCells(mesh, 0, mesh.nodeCounts()[2] - 1, [&](double e, std::ptrdiff_t base) {
        double fm[3][3];
        deformationGradient(u + base, off, kCentre.g, invH, fm);
        // A NaN or an inverted cell makes the bound infinite: the step is refused or capped.
        const double r = acousticBound(fm, mu, bulk) / rest;
        worst = std::max(
            worst, std::isnan(r) ? std::numeric_limits<double>::infinity() : e / mCellEMax * r);
    });
    // Below the rest state (tension) the bound is kept at the rest value: stiffness lost to
    // stretching is not counted on.
    return mOmegaRest * std::sqrt(std::max(1.0, worst));
}

double TledForces::criticalTimeStep(double omega, double extraOmega2) const noexcept {
    const double w = std::sqrt(omega * omega + std::max(0.0, extraOmega2));
    const ElasticMaterial& m = mModel.material();
    const double xi = 0.5 * (m.dampingAlpha / w + m.dampingBeta * w);
    return 2.0 / (w * (std::sqrt(1.0 + xi * xi) + xi));
}

}  // namespace palp::fem
