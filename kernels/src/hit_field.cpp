/// @file
/// HitField: a bit per cell that can reach a first-hit threshold, and per-block distances to
/// the blocks that have one.
#include "palp/kernels/hit_field.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <limits>
#include <string>
#include <vector>

#include "palp/base/error.h"
#include "palp/base/parallel.h"
#include "view_table.h"

namespace palp::kernels {

namespace {

using Table = detail::ViewTable;
constexpr int kPad = Table::kPad;

/// True when a first-hit sample in cell (x, y, z) of the padded copy @p src can reach @p thr:
/// the cell's corner maximum, raised by the hair of the view's 4^3 sub-block bounds (the
/// rounding of the blend, and positions a float rounding outside the cell). NaN corners never
/// raise the bound; an all-NaN cell never reaches a threshold.
bool cornersCanReach(const float* src, int x, int y, int z, float thr) noexcept {
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

}  // namespace

HitField::HitField(const VolumeView& view, float threshold) : mView(&view), mThreshold(threshold) {
    if (std::isnan(threshold))
        throw ValueError("hit field threshold: expected a number, found NaN");
    const Table& tb = detail::viewTable(view);
    const std::size_t copies =
        tb.padded ? tb.paddedSize / static_cast<std::size_t>(Table::kPadded) : 0;
    // Copies whose 4^3 sub-block bounds are all below the threshold have no cell that can reach
    // it (each cell's bound is at most its sub-block's): they share mask 0.
    std::vector<std::uint32_t> maskOf(copies, 0);
    std::vector<std::size_t> hot;
    for (std::size_t c = 0; c < copies; ++c) {
        const float* b = tb.subMax + c * Table::kSubBlocks;
        if (std::any_of(b, b + Table::kSubBlocks, [&](float v) { return v >= threshold; }))
            hot.push_back(c);
    }
    mHotCopies = hot.size();
    constexpr std::size_t kMaxMasks = std::size_t{1} << (32 - kDistanceBits);
    if (hot.size() + 1 > kMaxMasks)
        throw ValueError("hit field at threshold " + std::to_string(threshold) +
                         ": expected at most " + std::to_string(kMaxMasks - 1) +
                         " block copies that can reach it, found " + std::to_string(hot.size()));
    mMask.assign(hot.size() + 1, MaskLine{});
    mCopy.assign(hot.size() + 1, nullptr);
    mCopyOffset.assign(hot.size() + 1, 0);
    mCopyOffsetsValid = tb.paddedSize < (std::size_t{1} << 31) - 1024;
    for (std::size_t h = 0; h < hot.size(); ++h) {
        maskOf[hot[h]] = static_cast<std::uint32_t>(h + 1);
        const std::size_t at = hot[h] * static_cast<std::size_t>(Table::kPadded);
        mCopy[h + 1] = tb.padded + at;
        mCopyOffset[h + 1] = mCopyOffsetsValid ? static_cast<std::int32_t>(at) : 0;
    }
    const float* padded = tb.padded;
    const float* subMax = tb.subMax;
    MaskLine* masks = mMask.data();
    parallelForEach<std::size_t>(0, hot.size(), [&](std::size_t h) {
        const std::size_t c = hot[h];
        const float* src = padded + c * static_cast<std::size_t>(Table::kPadded);
        const float* sb = subMax + c * Table::kSubBlocks;
        MaskLine& m = masks[h + 1];
        for (int x = 0; x < 8; ++x)
            for (int y = 0; y < 8; ++y)
                for (int z = 0; z < 8; ++z) {
                    const int s = ((x >> 2) << 2) | ((y >> 2) << 1) | (z >> 2);
                    if (sb[s] >= threshold && cornersCanReach(src, x, y, z, threshold)) {
                        const int l = (x * 8 + y) * 8 + z;
                        m.w[l >> 5] |= std::uint32_t{1} << (l & 31);
                    }
                }
    });
    // Per table block: its copy's mask index, then the block distances in the low bits.
    std::vector<std::uint32_t> blockMask(tb.data.size());
    for (std::size_t b = 0; b < tb.data.size(); ++b)
        blockMask[b] = maskOf[static_cast<std::size_t>(tb.data[b] - tb.padded) /
                              static_cast<std::size_t>(Table::kPadded)];
    // Block distances: the same transform over the block grid, each axis in windows of
    // kFarBlocks (farther blocks only cap the distance).
    std::vector<std::uint8_t> distance(tb.data.size());
    for (std::size_t b = 0; b < tb.data.size(); ++b)
        distance[b] = blockMask[b] != 0 ? 0 : kFarBlocks;
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
                        distance[static_cast<std::size_t>(base + i * st)];
                for (std::int64_t i = 0; i < len; ++i) {
                    int best = line[static_cast<std::size_t>(i)];
                    const std::int64_t lo = std::max<std::int64_t>(0, i - kFarBlocks + 1);
                    const std::int64_t hi = std::min<std::int64_t>(len - 1, i + kFarBlocks - 1);
                    for (std::int64_t j = lo; j <= hi; ++j)
                        best = std::min(
                            best, std::max(static_cast<int>(std::abs(i - j)),
                                           static_cast<int>(line[static_cast<std::size_t>(j)])));
                    distance[static_cast<std::size_t>(base + i * st)] =
                        static_cast<std::uint8_t>(best);
                }
            }
    }
    mEntry.resize(tb.data.size());
    for (std::size_t b = 0; b < tb.data.size(); ++b)
        mEntry[b] = (blockMask[b] << kDistanceBits) | distance[b];
}

}  // namespace palp::kernels
