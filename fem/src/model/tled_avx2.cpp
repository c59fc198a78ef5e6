// TLED's one-point kernel four cells at a time with AVX2 and FMA (tled_avx2.h).
#include "model/tled_avx2.h"

#ifdef PALP_TLED_AVX2
#include <immintrin.h>

namespace palp::fem::detail {

namespace {

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

/// The one-point element of four cells (lanes) in place: @p v holds their nodal displacements
/// per component and corner on entry and their nodal forces on return; @p e their moduli,
/// @p active the lanes with e != 0 (the others get J = 1 and zero forces).
__attribute__((target("avx2,fma"))) inline void onePointLanes(__m256d (&v)[3][8], __m256d e,
                                                              __m256d active,
                                                              const OnePointConstants& k) noexcept {
    const __m256d one = _mm256_set1_pd(1.0);
    const double gradScale = k.gradScale, area = k.area, mu1 = k.mu1, bulk1 = k.bulk1,
                 hourglass8 = k.hourglass8;
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
}

/// Four nodes' xyz at @p p[0..3] (any places) as their x, y and z components.
__attribute__((target("avx2,fma"))) inline void gatherNodes4(const double* const (&p)[4],
                                                             __m256d& x, __m256d& y,
                                                             __m256d& z) noexcept {
    __m256d r[4];
    for (int l = 0; l < 4; ++l)
        r[l] = _mm256_insertf128_pd(_mm256_castpd128_pd256(_mm_loadu_pd(p[l])),
                                    _mm_load_sd(p[l] + 2), 1);  // x y z 0
    const __m256d t0 = _mm256_unpacklo_pd(r[0], r[1]), t1 = _mm256_unpackhi_pd(r[0], r[1]);
    const __m256d t2 = _mm256_unpacklo_pd(r[2], r[3]), t3 = _mm256_unpackhi_pd(r[2], r[3]);
    x = _mm256_permute2f128_pd(t0, t2, 0x20);
    z = _mm256_permute2f128_pd(t0, t2, 0x31);
    y = _mm256_permute2f128_pd(t1, t3, 0x20);
}

/// Adds four nodes' forces (x, y and z components) to the xyz at @p p[0..3], one node after
/// the other (two of them may be the same node).
__attribute__((target("avx2,fma"))) inline void scatterAddNodes4(double* const (&p)[4], __m256d x,
                                                                 __m256d y, __m256d z) noexcept {
    const __m256d zero = _mm256_setzero_pd();
    const __m256d lo = _mm256_permute2f128_pd(x, z, 0x20), hi = _mm256_permute2f128_pd(x, z, 0x31);
    const __m256d y01 = _mm256_permute2f128_pd(y, zero, 0x20);
    const __m256d y23 = _mm256_permute2f128_pd(y, zero, 0x31);
    const __m256d r[4] = {_mm256_unpacklo_pd(lo, y01), _mm256_unpackhi_pd(lo, y01),
                          _mm256_unpacklo_pd(hi, y23), _mm256_unpackhi_pd(hi, y23)};
    for (int l = 0; l < 4; ++l) {
        _mm_storeu_pd(p[l], _mm_add_pd(_mm_loadu_pd(p[l]), _mm256_castpd256_pd128(r[l])));
        _mm_store_sd(p[l] + 2, _mm_add_sd(_mm_load_sd(p[l] + 2), _mm256_extractf128_pd(r[l], 1)));
    }
}

}  // namespace

__attribute__((target("avx2,fma"))) void onePointRowAvx2(const double* __restrict ub,
                                                         double* __restrict fb, const double* rowE,
                                                         int groups,
                                                         const std::ptrdiff_t (&offset)[8],
                                                         const OnePointConstants& k) noexcept {
    const __m256d zero = _mm256_setzero_pd();
    for (int g = 0; g < groups; ++g) {
        const __m256d e = _mm256_loadu_pd(rowE + 4 * g);
        const __m256d active = _mm256_cmp_pd(e, zero, _CMP_NEQ_OQ);
        if (_mm256_movemask_pd(active) == 0) continue;
        const double* u = ub + 12 * static_cast<std::ptrdiff_t>(g);
        __m256d v[3][8];
        for (int a = 0; a < 8; ++a) loadNodes4(u + offset[a], v[0][a], v[1][a], v[2][a]);
        onePointLanes(v, e, active, k);
        double* fg = fb + 12 * static_cast<std::ptrdiff_t>(g);
        for (int a = 0; a < 8; ++a) addNodes4(fg + offset[a], v[0][a], v[1][a], v[2][a]);
    }
}

__attribute__((target("avx2,fma"))) void onePointCellsAvx2(const double* __restrict u,
                                                           double* __restrict f,
                                                           const std::ptrdiff_t (&base)[4],
                                                           const double (&cellE)[4],
                                                           const std::ptrdiff_t (&offset)[8],
                                                           const OnePointConstants& k) noexcept {
    const __m256d e = _mm256_loadu_pd(cellE);
    const __m256d active = _mm256_cmp_pd(e, _mm256_setzero_pd(), _CMP_NEQ_OQ);
    if (_mm256_movemask_pd(active) == 0) return;
    __m256d v[3][8];
    for (int a = 0; a < 8; ++a) {
        const double* const p[4] = {u + base[0] + offset[a], u + base[1] + offset[a],
                                    u + base[2] + offset[a], u + base[3] + offset[a]};
        gatherNodes4(p, v[0][a], v[1][a], v[2][a]);
    }
    onePointLanes(v, e, active, k);
    for (int a = 0; a < 8; ++a) {
        double* const p[4] = {f + base[0] + offset[a], f + base[1] + offset[a],
                              f + base[2] + offset[a], f + base[3] + offset[a]};
        scatterAddNodes4(p, v[0][a], v[1][a], v[2][a]);
    }
}

}  // namespace palp::fem::detail

#endif
