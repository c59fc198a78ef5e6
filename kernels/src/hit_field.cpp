/// @file
/// HitField: per-cell Chebyshev distances to the cells that can reach a first-hit threshold.
#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <limits>
#include <string>
#include <vector>

#include "palp/error.h"
#include "palp/kernels/volume_ray.h"
#include "palp/parallel.h"

namespace palp::kernels {

namespace {

using Table = VolumeView::Table;
constexpr int kPad = Table::kPad;

/// True when a first-hit sample in cell (x, y, z) of the padded copy @p src can reach @p thr:
/// the cell's corner maximum, raised by the hair of the view's 4^3 sub-block bounds (the
/// rounding of the blend, and positions a float rounding outside the cell). NaN corners never
/// raise the bound; an all-NaN cell never reaches a threshold.
bool cellCanReach(const float* src, int x, int y, int z, float thr) noexcept {
    float mx = -std::numeric_limits<float>::infinity();
    float mn = std::numeric_limits<float>::infinity();
    for (int i = 0; i < 8; ++i) {
        const float v =
            src[((x + ((i >> 2) & 1)) * kPad + y + ((i >> 1) & 1)) * kPad + z + (i & 1)];
        if (v > mx) mx = v;
        if (v < mn) mn = v;
    }
    float bound = mx + (mx - mn) * 1e-4f + std::fabs(mx) * 1e-6f;
    if (!(bound >= mx)) bound = mx;
    return bound >= thr;
}

/// One axis of the Chebyshev distance transform over an 8^3 block: d(i) = min_j max(|i - j|,
/// d(j)) along every line of axis @p stride.
void transformAxis(std::uint8_t (&d)[HitField::kCells], int stride) noexcept {
    const int s1 = stride == 64 ? 8 : 64, s2 = stride == 1 ? 8 : 1;
    for (int a = 0; a < 8; ++a)
        for (int b = 0; b < 8; ++b) {
            const int o = a * s1 + b * s2;
            std::uint8_t in[8], outv[8];
            for (int i = 0; i < 8; ++i) in[i] = d[o + i * stride];
            for (int i = 0; i < 8; ++i) {
                int best = in[i];
                for (int j = 0; j < 8; ++j)
                    best = std::min(best, std::max(std::abs(i - j), static_cast<int>(in[j])));
                outv[i] = static_cast<std::uint8_t>(best);
            }
            for (int i = 0; i < 8; ++i) d[o + i * stride] = outv[i];
        }
}

}  // namespace

HitField::HitField(const VolumeView& view, float threshold) : mView(&view), mThreshold(threshold) {
    if (std::isnan(threshold))
        throw ValueError("hit field threshold: expected a number, found NaN");
    const Table& tb = view.table();
    const std::size_t copies =
        tb.padded ? tb.paddedSize / static_cast<std::size_t>(Table::kPadded) : 0;
    // Copies whose 4^3 sub-block bounds are all below the threshold have no cell that can reach
    // it (each cell's bound is at most its sub-block's): they share one map of kFar.
    mOffset.assign(copies, 0);
    std::vector<std::size_t> hot;
    for (std::size_t c = 0; c < copies; ++c) {
        const float* b = tb.subMax + c * Table::kSubBlocks;
        if (std::any_of(b, b + Table::kSubBlocks, [&](float v) { return v >= threshold; }))
            hot.push_back(c);
    }
    mHotCopies = hot.size();
    const std::size_t bytesNeeded = (hot.size() + 1) * kCells + 4;
    if (bytesNeeded > std::numeric_limits<std::uint32_t>::max())
        throw ValueError("hit field at threshold " + std::to_string(threshold) +
                         ": expected at most 4 GiB of cell distances, found " +
                         std::to_string(bytesNeeded) + " bytes needed");
    mDistance.assign(bytesNeeded, kFar);
    for (std::size_t h = 0; h < hot.size(); ++h)
        mOffset[hot[h]] = static_cast<std::uint32_t>((h + 1) * kCells);
    const float* padded = tb.padded;
    const float* subMax = tb.subMax;
    std::uint8_t* dist = mDistance.data();
    parallelForEach<std::size_t>(0, hot.size(), [&](std::size_t h) {
        const std::size_t c = hot[h];
        const float* src = padded + c * static_cast<std::size_t>(Table::kPadded);
        const float* sb = subMax + c * Table::kSubBlocks;
        std::uint8_t d[kCells];
        for (int x = 0; x < 8; ++x)
            for (int y = 0; y < 8; ++y)
                for (int z = 0; z < 8; ++z) {
                    const int s = ((x >> 2) << 2) | ((y >> 2) << 1) | (z >> 2);
                    d[(x * 8 + y) * 8 + z] =
                        sb[s] >= threshold && cellCanReach(src, x, y, z, threshold) ? 0 : kFar;
                }
        transformAxis(d, 64);
        transformAxis(d, 8);
        transformAxis(d, 1);
        std::copy(d, d + kCells, dist + (h + 1) * kCells);
    });
    mBlockOffset.resize(tb.data.size());
    for (std::size_t b = 0; b < tb.data.size(); ++b)
        mBlockOffset[b] = mOffset[static_cast<std::size_t>(tb.data[b] - tb.padded) /
                                  static_cast<std::size_t>(Table::kPadded)];
    // Block distances: the same transform over the block grid, each axis in windows of
    // kFarBlocks (farther blocks only cap the distance).
    mBlockDistance.resize(tb.data.size());
    for (std::size_t b = 0; b < tb.data.size(); ++b)
        mBlockDistance[b] = mBlockOffset[b] != 0 ? 0 : kFarBlocks;
    const std::array<std::int64_t, 3> n = {tb.blocks[0], tb.blocks[1], tb.blocks[2]};
    const std::array<std::int64_t, 3> stride = {n[1] * n[2], n[2], 1};
    std::vector<std::uint8_t> line;
    for (int axis = 0; axis < 3; ++axis) {
        const int a1 = (axis + 1) % 3, a2 = (axis + 2) % 3;
        const std::int64_t len = n[static_cast<std::size_t>(axis)];
        line.resize(static_cast<std::size_t>(len));
        for (std::int64_t i1 = 0; i1 < n[static_cast<std::size_t>(a1)]; ++i1)
            for (std::int64_t i2 = 0; i2 < n[static_cast<std::size_t>(a2)]; ++i2) {
                const std::int64_t base = i1 * stride[static_cast<std::size_t>(a1)] +
                                          i2 * stride[static_cast<std::size_t>(a2)];
                const std::int64_t st = stride[static_cast<std::size_t>(axis)];
                for (std::int64_t i = 0; i < len; ++i)
                    line[static_cast<std::size_t>(i)] =
                        mBlockDistance[static_cast<std::size_t>(base + i * st)];
                for (std::int64_t i = 0; i < len; ++i) {
                    int best = line[static_cast<std::size_t>(i)];
                    const std::int64_t lo = std::max<std::int64_t>(0, i - kFarBlocks + 1);
                    const std::int64_t hi = std::min<std::int64_t>(len - 1, i + kFarBlocks - 1);
                    for (std::int64_t j = lo; j <= hi; ++j)
                        best = std::min(
                            best, std::max(static_cast<int>(std::abs(i - j)),
                                           static_cast<int>(line[static_cast<std::size_t>(j)])));
                    mBlockDistance[static_cast<std::size_t>(base + i * st)] =
                        static_cast<std::uint8_t>(best);
                }
            }
    }
}

}  // namespace palp::kernels
