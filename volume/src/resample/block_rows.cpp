// The resampler's row kernel over whole rows of leaf blocks (see block_rows.h).
#include "resample/block_rows.h"

#if (defined(__GNUC__) || defined(__clang__)) && defined(__x86_64__)
#include <immintrin.h>
#define PALP_ROWS_AVX2 1
#endif

#include <algorithm>
#include <cmath>
#include <cstddef>

#include "palp/base/simd.h"

namespace palp::volume::detail {

namespace {

constexpr int kBlockValues = kLeafDim * kLeafDim * kLeafDim;
/// Cache slots: pixel row mod 16 by slice mod 4. A row of blocks spans 8 voxel rows along y
/// and 8 along z, which read ~10 pixel rows of each of two or three slices; a collision only
/// recomputes.
constexpr int kCacheSlots = 64;

/// A voxel row of a row of blocks: lane x blends the column interpolations of the lower
/// slice's pixel rows (lo0, lo1) by frLo, the upper slice's (hi0, hi1) by frHi, then the two
/// slices by f, in the per-block kernel's operations and order; it stores the value, or the
/// background where the voxel is not active, at out[(x / 8) * 512 + (x % 8) * 64].
struct VoxelRow {
    const double *lo0, *lo1, *hi0, *hi1;
    double frLo, frHi, f;
    const std::uint32_t* inside;
    int width;
    std::ptrdiff_t lane;  // leaf-order stride of a step along the row (64, 8 or 1)
    float* out;
};

inline std::ptrdiff_t outIndex(int x, std::ptrdiff_t lane) {
    return static_cast<std::ptrdiff_t>(x / kLeafDim) * kBlockValues +
           static_cast<std::ptrdiff_t>(x % kLeafDim) * lane;
}

void voxelRowScalar(const VoxelRow& r, float threshold, float background) noexcept {
    const double gLo = 1 - r.frLo, gHi = 1 - r.frHi, g = 1 - r.f;
    for (int x = 0; x < r.width; ++x) {
        const double va = r.lo0[x] * gLo + r.lo1[x] * r.frLo;
        const double vb = r.hi0[x] * gHi + r.hi1[x] * r.frHi;
        const auto fv = static_cast<float>(va * g + vb * r.f);
        const bool keep = r.inside[x] != 0 && !(fv < threshold) && !(fv == background);
        r.out[outIndex(x, r.lane)] = keep ? fv : background;
    }
}

/// A pixel row's column interpolation at every voxel of a row of blocks: out[x] = p[ci] (1 - fc)
/// + p[ci + dc1] fc, in double, as the per-block kernel computes each voxel's.
struct ColumnRow {
    const float* pixels;
    const int* ci;
    const double *fc, *gc;
    std::ptrdiff_t dc1;
    int width;
    double* out;
};

void columnRowScalar(const ColumnRow& c) noexcept {
    for (int x = 0; x < c.width; ++x) {
        const float* p = c.pixels + c.ci[x];
        c.out[x] = static_cast<double>(p[0]) * c.gc[x] + static_cast<double>(p[c.dc1]) * c.fc[x];
    }
}

#ifdef PALP_ROWS_AVX2
/// voxelRowScalar four voxels at a time (every operation the scalar one in double, no FMA).
/// The width is a whole number of blocks, so four lanes never straddle two blocks.
__attribute__((target("avx2"))) void voxelRowAvx2(const VoxelRow& r, float threshold,
                                                  float background) noexcept {
    const __m256d gLo = _mm256_set1_pd(1 - r.frLo), fLo = _mm256_set1_pd(r.frLo);
    const __m256d gHi = _mm256_set1_pd(1 - r.frHi), fHi = _mm256_set1_pd(r.frHi);
    const __m256d g = _mm256_set1_pd(1 - r.f), f = _mm256_set1_pd(r.f);
    const __m128 thr = _mm_set1_ps(threshold), bg = _mm_set1_ps(background);
    const std::ptrdiff_t lane = r.lane;
    for (int x = 0; x < r.width; x += 4) {
        const __m256d va = _mm256_add_pd(_mm256_mul_pd(_mm256_loadu_pd(r.lo0 + x), gLo),
                                         _mm256_mul_pd(_mm256_loadu_pd(r.lo1 + x), fLo));
        const __m256d vb = _mm256_add_pd(_mm256_mul_pd(_mm256_loadu_pd(r.hi0 + x), gHi),
                                         _mm256_mul_pd(_mm256_loadu_pd(r.hi1 + x), fHi));
        const __m128 fv =
            _mm256_cvtpd_ps(_mm256_add_pd(_mm256_mul_pd(va, g), _mm256_mul_pd(vb, f)));
        // keep: inside, !(fv < threshold), !(fv == background) (NaN kept, as the scalar rows).
        const __m128 in =
            _mm_castsi128_ps(_mm_loadu_si128(reinterpret_cast<const __m128i*>(r.inside + x)));
        const __m128 keep = _mm_and_ps(
            in, _mm_and_ps(_mm_cmp_ps(fv, thr, _CMP_NLT_UQ), _mm_cmp_ps(fv, bg, _CMP_NEQ_UQ)));
        alignas(16) float v[4];
        _mm_store_ps(v, _mm_blendv_ps(bg, fv, keep));
        float* o = r.out + outIndex(x, lane);
        o[0] = v[0];
        o[lane] = v[1];
        o[2 * lane] = v[2];
        o[3 * lane] = v[3];
    }
}
#endif

}  // namespace

int blockRowAxis(const FillContext& ctx) {
    if (ctx.referenceOnly || ctx.perBlockRows) return -1;
    const SliceSampler& sm = ctx.sampler;
    if (sm.sliceCount() < 2) return -1;
    // The per-block kernel's row axis (fillBracketedBlock): the normal changes least along it.
    const LatticeSteps steps = latticeSteps(ctx);
    const Eigen::Vector3d& ds = steps.ds;
    const Eigen::Matrix<double, 2, 3>& dm = steps.dm;
    const int a = steps.rowAxis;
    const int b = (a + 1) % 3, c = (a + 2) % 3;
    // Rows along a keep the normal and the row coordinate; the column coordinate does not
    // change across rows; every slice at the same column offset.
    if (ds[a] != 0.0 || dm(1, a) != 0.0 || dm(0, b) != 0.0 || dm(0, c) != 0.0) return -1;
    for (std::size_t k = 1; k < sm.sliceCount(); ++k)
        if (sm.inPlaneOffset(k).x() != sm.inPlaneOffset(0).x()) return -1;
    return a;
}

void fillBlockRow(const FillContext& ctx, int a, int rowB, int rowC, int first, int last,
                  std::size_t bracket, std::size_t bracketEnd, BlockRowScratch& s) {
    const SliceSampler& sm = ctx.sampler;
    const Eigen::Vector3d& step = ctx.lat.step;
    const std::array<std::int64_t, 3>& dims = ctx.lat.dims;
    const Eigen::Matrix<double, 2, 3>& M = sm.inPlaneFromWorld();
    const LatticeSteps steps = latticeSteps(ctx);
    const Eigen::Vector3d& ds = steps.ds;
    const Eigen::Matrix<double, 2, 3>& dm = steps.dm;
    // Named copies, not a structured binding: the lambdas below use them, and clang before 16
    // (Debian's 14, the fuzz preset) refuses to capture structured bindings.
    const PixelGrid pix = pixelGrid(sm);
    const int cols = pix.cols, c0max = pix.c0max, r0max = pix.r0max;
    const double cmax = pix.cmax, rmax = pix.rmax, mc = pix.mc, mr = pix.mr;
    const std::ptrdiff_t dc1 = pix.dc1, dr1 = pix.dr1;
    const float threshold = ctx.threshold, background = ctx.background;
    const int width = (last - first + 1) * kLeafDim;
    const auto w = static_cast<std::size_t>(width);
    const int b = (a + 1) % 3, c = (a + 2) % 3;
    constexpr std::ptrdiff_t kStride[3] = {kLeafDim * kLeafDim, kLeafDim, 1};
    // The corner of block @p ba of the row (the lattice index of its first voxel, in metres).
    const auto cornerOf = [&](int ba) {
        Eigen::Vector3d index;
        index[a] = ba * kLeafDim;
        index[b] = rowB * kLeafDim;
        index[c] = rowC * kLeafDim;
        return Eigen::Vector3d(ctx.lat.lo + step.cwiseProduct(index));
    };

    // Each voxel's column, from its own block's corner as the per-block kernel finds it.
    s.ci.resize(w);
    s.fc.resize(w);
    s.gc.resize(w);
    s.inside.resize(w);
    const double offC = sm.inPlaneOffset(bracket).x();
    for (int ba = first; ba <= last; ++ba) {
        const Eigen::Vector2d m0 = M * cornerOf(ba);
        const auto na = static_cast<int>(
            std::min<std::int64_t>(kLeafDim, dims[static_cast<std::size_t>(a)] - ba * kLeafDim));
        for (int t = 0; t < kLeafDim; ++t) {
            const auto x = static_cast<std::size_t>((ba - first) * kLeafDim + t);
            double cc = m0.x() + dm(0, a) * t + offC;
            s.inside[x] = t < na && cc >= -mc && cc <= cmax + mc ? ~std::uint32_t{0} : 0;
            cc = std::clamp(cc, 0.0, cmax);
            s.ci[x] = std::min(static_cast<int>(cc), c0max);
            s.fc[x] = cc - s.ci[x];
            s.gc[x] = 1 - s.fc[x];
        }
    }
#ifdef PALP_ROWS_AVX2
    const bool simd = palp::avx2Enabled() && !ctx.scalarRows;
    const auto kernel = simd ? voxelRowAvx2 : voxelRowScalar;
#else
    const auto kernel = voxelRowScalar;
#endif
    s.values.assign(w / kLeafDim * kBlockValues, background);
    s.cache.resize(kCacheSlots * w);
    s.tags.assign(kCacheSlots, nullptr);
    // A pixel row's column interpolation across the row of blocks (cached by slot).
    const auto interpolated = [&](const float* pixels, int pixelRow, std::size_t slice) {
        const int slot = (pixelRow & 15) | static_cast<int>((slice & 3u) << 4);
        double* out = s.cache.data() + static_cast<std::size_t>(slot) * w;
        if (s.tags[static_cast<std::size_t>(slot)] == pixels)
            return static_cast<const double*>(out);
        s.tags[static_cast<std::size_t>(slot)] = pixels;
        // Scalar: AVX2 gathers of the two pixels were slower here (0.051 -> 0.058 s resampling
        // the head CT at 0.5 mm on a 2-vCPU AMD EPYC).
        columnRowScalar({pixels, s.ci.data(), s.fc.data(), s.gc.data(), dc1, width, out});
        return static_cast<const double*>(out);
    };
    struct Rows {
        const float* p0;
        int ri;
        double fr;
        bool insideR;
    };
    const auto pixelRows = [&](std::size_t k, double rr) {
        Rows pr{};
        pr.insideR = rr >= -mr && rr <= rmax + mr;
        rr = std::clamp(rr, 0.0, rmax);
        pr.ri = std::min(static_cast<int>(rr), r0max);
        pr.fr = rr - pr.ri;
        pr.p0 = sm.sliceData(k) + static_cast<std::ptrdiff_t>(pr.ri) * cols;
        return pr;
    };

    // The normal and row coordinates of a voxel row do not change along a: every block of the
    // row of blocks has the first one's.
    const Eigen::Vector3d bmin = cornerOf(first);
    const double s0 = bmin.dot(ctx.g.normal);
    const Eigen::Vector2d m0 = M * bmin;
    const int nb = static_cast<int>(
        std::min<std::int64_t>(kLeafDim, dims[static_cast<std::size_t>(b)] - rowB * kLeafDim));
    const int nc = static_cast<int>(
        std::min<std::int64_t>(kLeafDim, dims[static_cast<std::size_t>(c)] - rowC * kLeafDim));
    const int next = dr1 != 0 ? 1 : 0;
    std::size_t ka = bracket;
    for (int ob = 0; ob < nb; ++ob) {
        for (int oc = 0; oc < nc; ++oc) {
            const double sp = s0 + ds[b] * ob + ds[c] * oc;
            const double yRow = m0.y() + dm(1, b) * ob + dm(1, c) * oc;
            std::size_t k0 = 0, k1 = 0;
            double f = 0;
            if (!sm.blendAt(sp, bracket, bracketEnd, ka, k0, k1, f)) continue;
            const Rows lo = pixelRows(k0, yRow + sm.inPlaneOffset(k0).y());
            const Rows hi = pixelRows(k1, yRow + sm.inPlaneOffset(k1).y());
            if (!lo.insideR && !hi.insideR) continue;
            const VoxelRow row{interpolated(lo.p0, lo.ri, k0),
                               interpolated(lo.p0 + dr1, lo.ri + next, k0),
                               interpolated(hi.p0, hi.ri, k1),
                               interpolated(hi.p0 + dr1, hi.ri + next, k1),
                               lo.fr,
                               hi.fr,
                               f,
                               s.inside.data(),
                               width,
                               kStride[a],
                               s.values.data() + kStride[b] * ob + kStride[c] * oc};
            kernel(row, threshold, background);
        }
    }
}

}  // namespace palp::volume::detail
