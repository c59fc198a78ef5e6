// Filling the resampler's output leaves: a row kernel for blocks between two slices, the
// voxel-by-voxel reference for the rest, in parallel over leaf blocks.
#include <tbb/blocked_range.h>
#include <tbb/enumerable_thread_specific.h>

#if (defined(__GNUC__) || defined(__clang__)) && defined(__x86_64__)
#include <immintrin.h>
#define PALP_FILL_AVX2 1
#endif

#ifdef __SSE2__
#include <emmintrin.h>
#endif

#include <algorithm>
#include <array>
#include <cstdint>
#include <limits>
#include <memory>
#include <string>
#include <vector>

#include "palp/base/error.h"
#include "palp/base/parallel.h"
#include "palp/base/simd.h"
#include "resample/block_rows.h"
#include "resample/slice_sampler.h"

namespace palp::volume::detail {

namespace {

/// Sorted slices per group of blocks (fillTree): the band of slices a group reads is about this
/// many plus the slices one block spans along the normal.
constexpr std::size_t kSlicesPerGroup = 16;

/// Values of one leaf block (the sink's memory for the thread's next leaf) and its active mask,
/// filled densely by one thread; a block that stays inactive leaves its leaf to the next block,
/// so it costs no allocation, and an active one's values are filled in place, not copied.
struct DenseBlock {
    float* values = nullptr;  // the sink's (LeafSink::values())
    LeafT::NodeMaskType mask;
};

/// One slice's bilinear sample at (c, r) for the row kernel: the pixel centres clamped as in
/// sampleSlice() (the geometry is finite, analyse() checked it, so no NaN test).
struct SliceView {
    const float* data = nullptr;
    double offC = 0, offR = 0;  // (c, r) = (px, py) + offset
};

/// A slice's two pixel rows around a planar row's r coordinate (fillBracketedBlock).
struct PixelRows {
    const float* p0;  // pixel row at or below r
    const float* p1;  // the next pixel row (the same at the last row)
    double fr;
    bool insideR;
};

/// A planar row of a block (fillBracketedBlock): voxel t has the column coordinate
/// (x0 + step t) + off on each slice of the pair, and lies at @p offset + stride t in the block.
struct PlanarRow {
    double x0, step, offLo, offHi;
    double f;  // blend weight of the upper slice
    int count, offset, stride;
};

/// The column geometry of a slice: clamp bounds and the extent over which a sample counts as
/// inside (edge pixels extended by the margin).
struct Columns {
    double lowC, highC, cmax;
    int c0max;
    std::ptrdiff_t dc1;
};

#ifdef PALP_FILL_AVX2
#define PALP_FILL_AVX2_INLINE __attribute__((target("avx2"), always_inline)) inline

/// base[ci] for four columns, as doubles.
PALP_FILL_AVX2_INLINE __m256d gatherAvx2(const float* base, __m128i ci) {
    return _mm256_cvtps_pd(_mm_i32gather_ps(base, ci, 4));
}

/// w[i] for the four low lanes of @p i, as doubles.
PALP_FILL_AVX2_INLINE __m256d pickAvx2(__m256 w, __m256i i) {
    return _mm256_cvtps_pd(_mm256_castps256_ps128(_mm256_permutevar8x32_ps(w, i)));
}

/// The clamped bilinear samples of four voxels on one slice's pixel rows, with the scalar
/// kernel's double-precision operations in the same order (no FMA), so each lane is bit for bit
/// the scalar sample.
PALP_FILL_AVX2_INLINE __m256d sampleRowsAvx2(const PixelRows& pr, const Columns& cs, __m256d cc) {
    const __m256d one = _mm256_set1_pd(1.0);
    // std::clamp(cc, 0, cmax): max(0, cc) keeps cc when equal (-0.0), min(cmax, .) as clamp.
    cc = _mm256_min_pd(_mm256_set1_pd(cs.cmax), _mm256_max_pd(_mm256_setzero_pd(), cc));
    const __m128i ci = _mm_min_epi32(_mm256_cvttpd_epi32(cc), _mm_set1_epi32(cs.c0max));
    const __m256d fc = _mm256_sub_pd(cc, _mm256_cvtepi32_pd(ci));
    const __m256d gc = _mm256_sub_pd(one, fc);
    __m256d p00, p01, p10, p11;  // (row, column) pixels: p0[ci], p0[ci + dc1], p1[...]
    // The clamped columns are monotonic along the row, so the four lanes' pixels lie between
    // lane 0's and lane 3's: when they fit in eight pixels of the row, two loads and lane
    // permutes fetch them (the same values as the gathers, which cost more).
    const int ca = _mm_cvtsi128_si32(ci), cb = _mm_extract_epi32(ci, 3);
    const int base = std::min(ca, cb);
    const int cols = cs.c0max + 1 + static_cast<int>(cs.dc1);
    if (std::max(ca, cb) + static_cast<int>(cs.dc1) - base < 8 && base + 8 <= cols) {
        const __m256i i0 = _mm256_castsi128_si256(_mm_sub_epi32(ci, _mm_set1_epi32(base)));
        const __m256i i1 = _mm256_add_epi32(i0, _mm256_set1_epi32(static_cast<int>(cs.dc1)));
        const __m256 w0 = _mm256_loadu_ps(pr.p0 + base), w1 = _mm256_loadu_ps(pr.p1 + base);
        p00 = pickAvx2(w0, i0);
        p01 = pickAvx2(w0, i1);
        p10 = pickAvx2(w1, i0);
        p11 = pickAvx2(w1, i1);
    } else {
        p00 = gatherAvx2(pr.p0, ci);
        p01 = gatherAvx2(pr.p0 + cs.dc1, ci);
        p10 = gatherAvx2(pr.p1, ci);
        p11 = gatherAvx2(pr.p1 + cs.dc1, ci);
    }
    const __m256d top = _mm256_add_pd(_mm256_mul_pd(p00, gc), _mm256_mul_pd(p01, fc));
    const __m256d bottom = _mm256_add_pd(_mm256_mul_pd(p10, gc), _mm256_mul_pd(p11, fc));
    return _mm256_add_pd(_mm256_mul_pd(top, _mm256_set1_pd(1 - pr.fr)),
                         _mm256_mul_pd(bottom, _mm256_set1_pd(pr.fr)));
}

/// The lanes of @p cc inside [lowC, highC], as a double mask.
PALP_FILL_AVX2_INLINE __m256d insideAvx2(const Columns& cs, __m256d cc) {
    return _mm256_and_pd(_mm256_cmp_pd(cc, _mm256_set1_pd(cs.lowC), _CMP_GE_OQ),
                         _mm256_cmp_pd(cc, _mm256_set1_pd(cs.highC), _CMP_LE_OQ));
}

/// fillBracketedBlock's planar row, four voxels at a time: the same values as the scalar loop
/// (every operation is the scalar one in double, lane by lane). Returns whether any voxel
/// became active.
__attribute__((target("avx2"))) bool planarRowAvx2(const PlanarRow& row, const Columns& cs,
                                                   const PixelRows& lo, const PixelRows& hi,
                                                   float threshold, float background,
                                                   DenseBlock& block) {
    const bool shared = row.offLo == row.offHi;
    const __m256d x0 = _mm256_set1_pd(row.x0), step = _mm256_set1_pd(row.step);
    const __m256d f = _mm256_set1_pd(row.f), g = _mm256_set1_pd(1 - row.f);
    const __m256d none = _mm256_setzero_pd();
    const __m128 thr = _mm_set1_ps(threshold), bg = _mm_set1_ps(background);
    bool any = false;
    for (int t0 = 0; t0 < row.count; t0 += 4) {
        const __m256d t = _mm256_add_pd(_mm256_set1_pd(t0), _mm256_setr_pd(0, 1, 2, 3));
        const __m256d px = _mm256_add_pd(x0, _mm256_mul_pd(step, t));
        const __m256d cLo = _mm256_add_pd(px, _mm256_set1_pd(row.offLo));
        const __m256d cHi = shared ? cLo : _mm256_add_pd(px, _mm256_set1_pd(row.offHi));
        const __m256d inLo = lo.insideR ? insideAvx2(cs, cLo) : none;
        const __m256d inHi = hi.insideR ? insideAvx2(cs, cHi) : none;
        const int lanes = std::min(row.count - t0, 4);
        int bits = _mm256_movemask_pd(_mm256_or_pd(inLo, inHi)) & ((1 << lanes) - 1);
        if (bits == 0) continue;
        const __m256d va = sampleRowsAvx2(lo, cs, cLo);
        const __m256d vb = sampleRowsAvx2(hi, cs, cHi);
        const __m128 fv =
            _mm256_cvtpd_ps(_mm256_add_pd(_mm256_mul_pd(va, g), _mm256_mul_pd(vb, f)));
        bits &= ~_mm_movemask_ps(
            _mm_or_ps(_mm_cmp_ps(fv, thr, _CMP_LT_OQ), _mm_cmp_ps(fv, bg, _CMP_EQ_OQ)));
        if (bits == 0) continue;
        alignas(16) float out[4];
        _mm_store_ps(out, fv);
        for (int j = 0; j < 4; ++j) {
            if (!(bits & (1 << j))) continue;
            const int offset = row.offset + row.stride * (t0 + j);
            block.values[static_cast<std::size_t>(offset)] = out[j];
            block.mask.setOn(static_cast<openvdb::Index>(offset));
        }
        any = true;
    }
    return any;
}

#endif

/// Stores the blend va (1 - f) + vb f of two slices' samples at @p offset when it passes the
/// threshold and differs from the background; returns whether it was stored.
inline bool storeBlend(DenseBlock& block, int offset, double va, double vb, double f,
                       float threshold, float background) noexcept {
    const auto fv = static_cast<float>(va * (1 - f) + vb * f);
    if (fv < threshold || fv == background) return false;
    block.values[static_cast<std::size_t>(offset)] = fv;
    block.mask.setOn(static_cast<openvdb::Index>(offset));
    return true;
}

/// Fills @p block for a block that lies within the slices' range, between slices [bracket,
/// bracketEnd]. Works along rows of the lattice axis most parallel to the slices: on a row the
/// normal coordinate and the in-plane coordinates are affine in the step, so they advance by
/// constant increments, the bracketing pair of slices changes rarely (and is cached), and each
/// voxel costs two clamped bilinear samples and a blend, with no matrix product or search.
/// The arithmetic is the reference's (valueAt): the same formulas in double.
/// Returns whether any voxel became active.
bool fillBracketedBlock(const FillContext& ctx, const openvdb::Coord& origin,
                        const Eigen::Vector3d& bmin, std::size_t bracket, std::size_t bracketEnd,
                        DenseBlock& block) {
    const SliceSampler& sm = ctx.sampler;
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
    const double s0 = bmin.dot(ctx.g.normal);
    const Eigen::Vector2d m0 = M * bmin;
    const int n[3] = {static_cast<int>(std::min<std::int64_t>(kLeafDim, dims[0] - origin.x())),
                      static_cast<int>(std::min<std::int64_t>(kLeafDim, dims[1] - origin.y())),
                      static_cast<int>(std::min<std::int64_t>(kLeafDim, dims[2] - origin.z()))};
    // Inner axis: the one along which the normal coordinate changes least.
    const int a = steps.rowAxis;
    const int b = (a + 1) % 3, c = (a + 2) % 3;
    constexpr int kStride[3] = {kLeafDim * kLeafDim, kLeafDim, 1};

    const auto sample = [&](const float* data, double cc, double rr, double& out) {
        const bool inside = cc >= -mc && cc <= cmax + mc && rr >= -mr && rr <= rmax + mr;
        cc = std::clamp(cc, 0.0, cmax);
        rr = std::clamp(rr, 0.0, rmax);
        const int ci = std::min(static_cast<int>(cc), c0max);
        const int ri = std::min(static_cast<int>(rr), r0max);
        const double fc = cc - ci;
        const double fr = rr - ri;
        const float* p =
            data + static_cast<std::ptrdiff_t>(ri) * cols + static_cast<std::ptrdiff_t>(ci);
        const double top = static_cast<double>(p[0]) * (1 - fc) + static_cast<double>(p[dc1]) * fc;
        const double bottom =
            static_cast<double>(p[dr1]) * (1 - fc) + static_cast<double>(p[dr1 + dc1]) * fc;
        out = top * (1 - fr) + bottom * fr;
        return inside;
    };

    // The blended pair (or a slice alone, k0 == k1, past the first or last) cached by index.
    std::size_t cached0 = std::numeric_limits<std::size_t>::max(), cached1 = cached0;
    SliceView lo, hi;
    const auto use = [&](std::size_t k0, std::size_t k1) {
        if (k0 == cached0 && k1 == cached1) return;
        cached0 = k0;
        cached1 = k1;
        lo = {sm.sliceData(k0), sm.inPlaneOffset(k0).x(), sm.inPlaneOffset(k0).y()};
        hi = {sm.sliceData(k1), sm.inPlaneOffset(k1).x(), sm.inPlaneOffset(k1).y()};
    };

    const float threshold = ctx.threshold, background = ctx.background;
    // Rows on which the normal coordinate and the in-plane row coordinate r are constant (the
    // x rows of an axial series, with or without gantry tilt): the slice pair, the blend weight
    // and both slices' pixel rows are found once per row, and each voxel interpolates along c
    // only. The arithmetic is the general path's, term for term, so the values are identical.
    const bool planarRows = ds[a] == 0.0 && dm(1, a) == 0.0;
#ifdef PALP_FILL_AVX2
    const bool simd = palp::avx2Enabled() && !ctx.scalarRows;
    const Columns columns{-mc, cmax + mc, cmax, c0max, dc1};
#endif
    const auto pixelRows = [&](const SliceView& sv, double rr) {
        PixelRows pr{};
        pr.insideR = rr >= -mr && rr <= rmax + mr;
        rr = std::clamp(rr, 0.0, rmax);
        const int ri = std::min(static_cast<int>(rr), r0max);
        pr.fr = rr - ri;
        pr.p0 = sv.data + static_cast<std::ptrdiff_t>(ri) * cols;
        pr.p1 = pr.p0 + dr1;
        return pr;
    };
    // The column coordinate clamped, split into its pixel and fraction (sampleRows' first half).
    struct Column {
        int ci;
        double fc;
    };
    const auto columnAt = [&](double cc) {
        cc = std::clamp(cc, 0.0, cmax);
        const int ci = std::min(static_cast<int>(cc), c0max);
        return Column{ci, cc - ci};
    };
    const auto bilinear = [&](const PixelRows& pr, Column col) {
        const int ci = col.ci;
        const double fc = col.fc;
        const double top =
            static_cast<double>(pr.p0[ci]) * (1 - fc) + static_cast<double>(pr.p0[ci + dc1]) * fc;
        const double bottom =
            static_cast<double>(pr.p1[ci]) * (1 - fc) + static_cast<double>(pr.p1[ci + dc1]) * fc;
        return top * (1 - pr.fr) + bottom * pr.fr;
    };
    const auto sampleRows = [&](const PixelRows& pr, double cc) {
        cc = std::clamp(cc, 0.0, cmax);
        const int ci = std::min(static_cast<int>(cc), c0max);
        const double fc = cc - ci;
        const double top =
            static_cast<double>(pr.p0[ci]) * (1 - fc) + static_cast<double>(pr.p0[ci + dc1]) * fc;
        const double bottom =
            static_cast<double>(pr.p1[ci]) * (1 - fc) + static_cast<double>(pr.p1[ci + dc1]) * fc;
        return top * (1 - pr.fr) + bottom * pr.fr;
    };

    bool any = false;
    std::size_t ka = bracket;
    for (int ob = 0; ob < n[b]; ++ob) {
        for (int oc = 0; oc < n[c]; ++oc) {
            const double sRow = s0 + ds[b] * ob + ds[c] * oc;
            const double xRow = m0.x() + dm(0, b) * ob + dm(0, c) * oc;
            const double yRow = m0.y() + dm(1, b) * ob + dm(1, c) * oc;
            int offset = kStride[b] * ob + kStride[c] * oc;
            if (planarRows) {
                std::size_t k0 = 0, k1 = 0;
                double f = 0;
                if (!sm.blendAt(sRow, bracket, bracketEnd, ka, k0, k1, f)) continue;
                use(k0, k1);
                const PixelRows rowsLo = pixelRows(lo, yRow + lo.offR);
                const PixelRows rowsHi = pixelRows(hi, yRow + hi.offR);
                if (!rowsLo.insideR && !rowsHi.insideR) continue;
                {
                    // The pixels of the block after next along the row: blocks run along the
                    // row's axis, and each row of a block reads its own slices' pixel rows, so
                    // these lines are fetched while this block and the next are filled (the
                    // row kernel waited on them: ~1/4 of its time on the generated series).
                    const double ahead = xRow + dm(0, a) * (2 * kLeafDim);
                    const int cLo = columnAt(ahead + lo.offC).ci;
                    const int cHi = columnAt(ahead + hi.offC).ci;
                    __builtin_prefetch(rowsLo.p0 + cLo);
                    __builtin_prefetch(rowsLo.p1 + cLo);
                    __builtin_prefetch(rowsHi.p0 + cHi);
                    __builtin_prefetch(rowsHi.p1 + cHi);
                }
#ifdef PALP_FILL_AVX2
                if (simd) {
                    const PlanarRow row{xRow, dm(0, a), lo.offC, hi.offC,
                                        f,    n[a],     offset,  kStride[a]};
                    any =
                        planarRowAvx2(row, columns, rowsLo, rowsHi, threshold, background, block) ||
                        any;
                    continue;
                }
#endif
                if (lo.offC == hi.offC) {
                    // Both slices at the same column coordinate (slices shifted only along
                    // their rows, as with gantry tilt): the column's pixel and fraction are
                    // found once for both, the same numbers as the loop below.
                    for (int t = 0; t < n[a]; ++t, offset += kStride[a]) {
                        const double cc = xRow + dm(0, a) * t + lo.offC;
                        if (!(cc >= -mc && cc <= cmax + mc)) continue;
                        const Column col = columnAt(cc);
                        any = storeBlend(block, offset, bilinear(rowsLo, col),
                                         bilinear(rowsHi, col), f, threshold, background) ||
                              any;
                    }
                    continue;
                }
                for (int t = 0; t < n[a]; ++t, offset += kStride[a]) {
                    const double px = xRow + dm(0, a) * t;
                    const double cLo = px + lo.offC, cHi = px + hi.offC;
                    const bool ina = rowsLo.insideR && cLo >= -mc && cLo <= cmax + mc;
                    const bool inb = rowsHi.insideR && cHi >= -mc && cHi <= cmax + mc;
                    if (!ina && !inb) continue;
                    any = storeBlend(block, offset, sampleRows(rowsLo, cLo),
                                     sampleRows(rowsHi, cHi), f, threshold, background) ||
                          any;
                }
                continue;
            }
            for (int t = 0; t < n[a]; ++t, offset += kStride[a]) {
                std::size_t k0 = 0, k1 = 0;
                double f = 0;
                if (!sm.blendAt(sRow + ds[a] * t, bracket, bracketEnd, ka, k0, k1, f)) continue;
                use(k0, k1);
                const double px = xRow + dm(0, a) * t;
                const double py = yRow + dm(1, a) * t;
                double va = 0, vb = 0;
                const bool ina = sample(lo.data, px + lo.offC, py + lo.offR, va);
                const bool inb = sample(hi.data, px + hi.offC, py + hi.offR, vb);
                if (!ina && !inb) continue;
                any = storeBlend(block, offset, va, vb, f, threshold, background) || any;
            }
        }
    }
    return any;
}

/// Fills @p block voxel by voxel through SliceSampler::valueAt (a block reaching past the first
/// or last slice; also the reference the row kernel is tested against).
/// Returns whether any voxel became active.
bool fillBlock(const FillContext& ctx, const openvdb::Coord& origin, DenseBlock& block) {
    const std::array<std::int64_t, 3>& dims = ctx.lat.dims;
    bool any = false;
    for (int i = 0; i < kLeafDim; ++i) {
        const int x = origin.x() + i;
        if (x >= dims[0]) break;
        for (int j = 0; j < kLeafDim; ++j) {
            const int y = origin.y() + j;
            if (y >= dims[1]) break;
            for (int k = 0; k < kLeafDim; ++k) {
                const int z = origin.z() + k;
                if (z >= dims[2]) break;
                const Eigen::Vector3d p =
                    ctx.lat.lo + ctx.lat.step.cwiseProduct(Eigen::Vector3d(x, y, z));
                double v = 0;
                if (!ctx.sampler.valueAt(p, v)) continue;
                const auto fv = static_cast<float>(v);
                if (fv < ctx.threshold || fv == ctx.background) continue;
                const openvdb::Index offset = LeafT::coordToOffset(openvdb::Coord(x, y, z));
                block.values[offset] = fv;
                block.mask.setOn(offset);
                any = true;
            }
        }
    }
    return any;
}

/// Sets @p mask to the voxels of the block @p values (leaf order) that differ from
/// @p background (==, as the kernels compare: NaN differs from everything); returns whether any
/// does.
bool activeMask(const float* values, float background, LeafT::NodeMaskType& mask) noexcept {
    std::uint64_t any = 0;
    for (openvdb::Index w = 0; w < LeafT::NodeMaskType::WORD_COUNT; ++w) {
        std::uint64_t bits = 0;
        const float* row = values + w * 64;
#ifdef __SSE2__
        const __m128 bg = _mm_set1_ps(background);
        for (unsigned j = 0; j < 16; ++j) {
            const auto equal =
                static_cast<unsigned>(_mm_movemask_ps(_mm_cmpeq_ps(_mm_loadu_ps(row + 4 * j), bg)));
            bits |= std::uint64_t{~equal & 0xFu} << (4 * j);
        }
#else
        for (unsigned i = 0; i < 64; ++i) bits |= std::uint64_t{!(row[i] == background)} << i;
#endif
        mask.getWord<std::uint64_t>(w) = bits;
        any |= bits;
    }
    return any != 0;
}

}  // namespace

void fillTree(const FillContext& ctx, const ProgressFn& progress, const SliceWindowFn& window) {
    const SliceSampler& sm = ctx.sampler;
    const std::size_t n = sm.sliceCount();
    const Eigen::Vector3d& step = ctx.lat.step;
    const std::array<std::int64_t, 3>& dims = ctx.lat.dims;
    const auto bx = static_cast<std::size_t>((dims[0] + kLeafDim - 1) / kLeafDim);
    const auto by = static_cast<std::size_t>((dims[1] + kLeafDim - 1) / kLeafDim);
    const auto bz = static_cast<std::size_t>((dims[2] + kLeafDim - 1) / kLeafDim);
    const std::size_t blocks = bx * by * bz;
    if (blocks > std::numeric_limits<std::uint32_t>::max()) {
        throw ValueError("resample: expected at most " +
                         std::to_string(std::numeric_limits<std::uint32_t>::max()) +
                         " leaf blocks of 8^3 voxels, found " + std::to_string(blocks) +
                         "; choose a larger voxel size or a crop");
    }
    const auto originOf = [&](std::size_t i) {
        return openvdb::Coord(static_cast<int>((i % bx) * kLeafDim),
                              static_cast<int>((i / bx % by) * kLeafDim),
                              static_cast<int>((i / (bx * by)) * kLeafDim));
    };
    const auto cornersOf = [&](const openvdb::Coord& origin, Eigen::Vector3d& bmin,
                               Eigen::Vector3d& bmax) {
        bmin = ctx.lat.lo + step.cwiseProduct(Eigen::Vector3d(origin.x(), origin.y(), origin.z()));
        bmax = bmin + step * (kLeafDim - 1);
    };
    // The units of work: single blocks, or whole rows of blocks along axis ra where every
    // voxel row of such a row can be set up once (fillBlockRow). Row unit u is the row at block
    // u % (blocks along rb), u / (blocks along rb) along the next two axes rb, rc.
    const int rowAxis = blockRowAxis(ctx);
    const bool byRows = rowAxis >= 0;
    const std::array<std::size_t, 3> nBlocks{bx, by, bz};
    const std::size_t ra = byRows ? static_cast<std::size_t>(rowAxis) : 0, rb = (ra + 1) % 3,
                      rc = (ra + 2) % 3;
    const std::size_t units = byRows ? nBlocks[rb] * nBlocks[rc] : blocks;
    // The linear index of block k along the row of row unit u.
    const auto rowBlock = [&](std::size_t u, std::size_t k) {
        std::array<std::size_t, 3> at{};
        at[ra] = k;
        at[rb] = u % nBlocks[rb];
        at[rc] = u / nBlocks[rb];
        return at[0] + bx * (at[1] + by * at[2]);
    };

    // Each unit that may hold active voxels goes to the group of the first slice it reads
    // (units wholly outside the slices hold none); the last slice it reads bounds the
    // group's band. One slice of margin either side covers the rounding of the voxel-by-voxel
    // path's normal coordinates against the corners'. (A row of blocks has the normal range of
    // each of its blocks.)
    constexpr std::uint32_t kNone = std::numeric_limits<std::uint32_t>::max();
    std::vector<std::uint32_t> groupOf(units), lastOf(units);
    palp::parallelForEach(
        std::size_t{0}, units,
        [&](std::size_t i) {
            Eigen::Vector3d bmin, bmax;
            cornersOf(originOf(byRows ? rowBlock(i, 0) : i), bmin, bmax);
            double smin = 0, smax = 0;
            sm.blockAlong(bmin, bmax, smin, smax);
            if (sm.outsideAlong(smin, smax)) {
                groupOf[i] = kNone;
                return;
            }
            const auto [first, last] = sm.slicesSpanned(smin, smax);
            groupOf[i] = static_cast<std::uint32_t>(first / kSlicesPerGroup);
            lastOf[i] = static_cast<std::uint32_t>(last);
        },
        std::size_t{4096});
    const std::size_t groups = (n + kSlicesPerGroup - 1) / kSlicesPerGroup;
    std::vector<std::size_t> start(groups + 1, 0), bandEnd(groups, 0);
    for (std::size_t i = 0; i < units; ++i) {
        if (groupOf[i] == kNone) continue;
        ++start[groupOf[i] + 1];
        bandEnd[groupOf[i]] = std::max<std::size_t>(bandEnd[groupOf[i]], lastOf[i]);
    }
    lastOf = {};
    for (std::size_t g = 0; g < groups; ++g) start[g + 1] += start[g];
    std::vector<std::uint32_t> order(start.back());
    {
        std::vector<std::size_t> next(start.begin(), start.end() - 1);
        for (std::size_t i = 0; i < units; ++i)
            if (groupOf[i] != kNone) order[next[groupOf[i]]++] = static_cast<std::uint32_t>(i);
    }
    groupOf = {};

    tbb::enumerable_thread_specific<DenseBlock> scratch;
    tbb::enumerable_thread_specific<BlockRowScratch> rowScratch;
    // One block by the per-block kernel (voxel by voxel for a single slice, and for the tests'
    // reference), filled in the sink's values for the thread's next leaf.
    const auto fillOne = [&](const openvdb::Coord& origin, const Eigen::Vector3d& bmin,
                             std::size_t bracket, std::size_t bracketEnd) {
        DenseBlock& block = scratch.local();
        block.values = ctx.sink.values();
        std::fill_n(block.values, LeafT::SIZE, ctx.background);
        block.mask.setOff();
        const bool any = bracket < n && !ctx.referenceOnly
                             ? fillBracketedBlock(ctx, origin, bmin, bracket, bracketEnd, block)
                             : fillBlock(ctx, origin, block);
        if (any) ctx.sink.take(origin, block.mask, block.values);
    };
    // A row of blocks: its candidate blocks through fillBlockRow, each with an active voxel
    // given to the sink.
    const auto fillRow = [&](std::size_t u) {
        BlockRowScratch& rs = rowScratch.local();
        const std::size_t along = nBlocks[ra];
        int first = -1, last = -1;
        std::size_t bracket = n, bracketEnd = n;
        std::vector<char>& candidate = rs.candidate;
        candidate.assign(along, 0);
        for (std::size_t k = 0; k < along; ++k) {
            Eigen::Vector3d bmin, bmax;
            cornersOf(originOf(rowBlock(u, k)), bmin, bmax);
            if (!sm.blockMayBeActive(bmin, bmax, bracket, bracketEnd)) continue;
            candidate[k] = 1;
            if (first < 0) first = static_cast<int>(k);
            last = static_cast<int>(k);
        }
        if (first < 0) return;
        if (bracket >= n) {  // no pair to blend (rows of blocks need two slices): as a block
            for (int k = first; k <= last; ++k) {
                if (!candidate[static_cast<std::size_t>(k)]) continue;
                const openvdb::Coord origin = originOf(rowBlock(u, static_cast<std::size_t>(k)));
                Eigen::Vector3d bmin, bmax;
                cornersOf(origin, bmin, bmax);
                fillOne(origin, bmin, n, n);
            }
            return;
        }
        fillBlockRow(ctx, rowAxis, static_cast<int>(u % nBlocks[rb]),
                     static_cast<int>(u / nBlocks[rb]), first, last, bracket, bracketEnd, rs);
        for (int k = first; k <= last; ++k) {
            if (!candidate[static_cast<std::size_t>(k)]) continue;
            float* values = rs.values.data() + static_cast<std::size_t>(k - first) * LeafT::SIZE;
            LeafT::NodeMaskType mask;
            if (!activeMask(values, ctx.background, mask)) continue;
            ctx.sink.take(originOf(rowBlock(u, static_cast<std::size_t>(k))), mask, values);
        }
    };
    for (std::size_t g = 0; g < groups; ++g) {
        if (start[g] < start[g + 1]) {
            if (window) {
                const std::size_t lo = g * kSlicesPerGroup > 0 ? g * kSlicesPerGroup - 1 : 0;
                window(lo, lo, std::min(bandEnd[g] + 1, n - 1));
            }
            palp::parallelFor(
                tbb::blocked_range<std::size_t>(start[g], start[g + 1], byRows ? 1 : 16),
                [&](const tbb::blocked_range<std::size_t>& r) {
                    for (std::size_t b = r.begin(); b != r.end(); ++b) {
                        if (byRows) {
                            fillRow(order[b]);
                            continue;
                        }
                        const openvdb::Coord origin = originOf(order[b]);
                        Eigen::Vector3d bmin, bmax;
                        cornersOf(origin, bmin, bmax);
                        std::size_t bracket = n, bracketEnd = n;
                        if (!sm.blockMayBeActive(bmin, bmax, bracket, bracketEnd)) continue;
                        fillOne(origin, bmin, bracket, bracketEnd);
                    }
                });
            ctx.sink.groupDone();
        }
        if (progress && !progress(static_cast<double>(g + 1) / static_cast<double>(groups))) {
            throw Error("resample: cancelled");
        }
    }
}

}  // namespace palp::volume::detail
