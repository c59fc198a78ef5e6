#include "palp/kernels/volume_view.h"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <limits>
#include <new>
#include <string>
#include <type_traits>

#include "palp/base/error.h"
#include "ray_sample.h"

namespace palp::kernels {

// ---------------------------------------------------------------------------------------------
// VolumeView

namespace {

/// The voxel size of @p grid (metres). @throw ValueError unless its transform is an isotropic
/// axis-aligned scale plus translation.
double isotropicVoxelSize(const openvdb::FloatGrid& grid) {
    const openvdb::math::Transform& xf = grid.transform();
    const openvdb::Vec3d o = xf.indexToWorld(openvdb::Vec3d(0, 0, 0));
    const openvdb::Vec3d ax = xf.indexToWorld(openvdb::Vec3d(1, 0, 0)) - o;
    const openvdb::Vec3d ay = xf.indexToWorld(openvdb::Vec3d(0, 1, 0)) - o;
    const openvdb::Vec3d az = xf.indexToWorld(openvdb::Vec3d(0, 0, 1)) - o;
    const double s = ax.x();
    const double tol = 1e-9 * std::fabs(s);
    const bool ok = xf.isLinear() && s > 0 && std::isfinite(s) && std::fabs(ax.y()) <= tol &&
                    std::fabs(ax.z()) <= tol && std::fabs(ay.x()) <= tol &&
                    std::fabs(ay.z()) <= tol && std::fabs(az.x()) <= tol &&
                    std::fabs(az.y()) <= tol && std::fabs(ay.y() - s) <= tol &&
                    std::fabs(az.z() - s) <= tol;
    if (!ok)
        throw ValueError(
            "volume view transform of grid '" + grid.getName() +
            "': expected an isotropic axis-aligned scale and translation, found voxel axes (" +
            std::to_string(ax.x()) + ", " + std::to_string(ay.y()) + ", " + std::to_string(az.z()) +
            ") m");
    return s;
}

/// The bounding box of @p tree's leaves and of its tiles that are active or not @p background.
openvdb::CoordBBox activeBounds(const openvdb::FloatTree& tree, float background) {
    openvdb::CoordBBox box;
    for (auto it = tree.cbeginLeaf(); it; ++it) box.expand(it->getNodeBoundingBox());
    {
        auto it = tree.cbeginValueAll();
        it.setMaxDepth(openvdb::FloatTree::ValueAllCIter::LEAF_DEPTH - 1);
        for (; it; ++it) {
            if (it.isTileValue() && (it.isValueOn() || *it != background)) {
                openvdb::CoordBBox tb;
                it.getBoundingBox(tb);
                box.expand(tb);
            }
        }
    }
    return box;
}

/// Table::subMax of the @p copies padded block copies at @p padded, into @p subMax.
void subBlockBounds(const float* padded, std::size_t copies, std::vector<float>& subMax) {
    subMax.assign(copies * Table::kSubBlocks, 0.0f);
    for (std::size_t c = 0; c < copies; ++c) {
        const float* src = padded + c * static_cast<std::size_t>(Table::kPadded);
        for (int sb = 0; sb < Table::kSubBlocks; ++sb) {
            const int x0 = 4 * ((sb >> 2) & 1), y0 = 4 * ((sb >> 1) & 1), z0 = 4 * (sb & 1);
            // NaN never reaches a threshold and never raises the bound; +-inf does.
            float mx = -std::numeric_limits<float>::infinity();
            float mn = std::numeric_limits<float>::infinity();
            for (int x = x0; x <= x0 + 4; ++x)
                for (int y = y0; y <= y0 + 4; ++y)
                    for (int z = z0; z <= z0 + 4; ++z) {
                        const float v = src[(x * Table::kPad + y) * Table::kPad + z];
                        if (v > mx) mx = v;
                        if (v < mn) mn = v;
                    }
            // A blend of values in [mn, mx] with weights in [0, 1] stays in [mn, mx] up to a few
            // ulps of mx; a run sample can sit a float rounding (well below 1e-4 voxel) outside
            // its cell, which extrapolates by that fraction of the range.
            float bound = mx + (mx - mn) * 1e-4f + std::fabs(mx) * 1e-6f;
            if (!(bound >= mx)) bound = mx;  // inf - inf, or an all-NaN sub-block
            subMax[c * Table::kSubBlocks + static_cast<std::size_t>(sb)] = bound;
        }
    }
}

}  // namespace

VolumeView::VolumeView(openvdb::FloatGrid::ConstPtr grid) : mGrid(std::move(grid)) {
    detail::ViewTable& tbl = *::new (static_cast<void*>(mTable)) detail::ViewTable;
    try {
        build(tbl);
    } catch (...) {
        tbl.~ViewTable();
        throw;
    }
}

VolumeView::~VolumeView() { detail::ViewAccess::table(*this).~ViewTable(); }

void VolumeView::build(detail::ViewTable& tbl) {
    if (!mGrid) throw ValueError("volume view grid: expected a FloatGrid, found a null pointer");
    const openvdb::Vec3d o = mGrid->transform().indexToWorld(openvdb::Vec3d(0, 0, 0));
    const double s = isotropicVoxelSize(*mGrid);
    mWorldOrigin = Eigen::Vector3d(o.x(), o.y(), o.z());
    mVoxelSize = s;
    mInvVoxelSize = 1.0 / s;
    mBackground = mGrid->background();
    const openvdb::FloatTree& tree = mGrid->tree();
    const openvdb::CoordBBox box = activeBounds(tree, mBackground);
    mEmpty = box.empty();
    if (mEmpty) {
        tbl.origin = {0, 0, 0};
        tbl.blocks = {0, 0, 0};
        return;
    }
    std::array<std::int64_t, 3> n{};
    std::int64_t total = 1;
    for (openvdb::Index a = 0; a < 3; ++a) {
        const std::int64_t lo = (static_cast<std::int64_t>(box.min()[a]) >> 3) - 1;
        const std::int64_t hi = (static_cast<std::int64_t>(box.max()[a]) >> 3) + 1;
        n[a] = hi - lo + 1;
        tbl.origin[a] = static_cast<std::int32_t>(lo * 8);
        total *= n[a];
        if (total > kMaxViewBlocks) break;
    }
    if (total > kMaxViewBlocks)
        throw ValueError("volume view of grid '" + mGrid->getName() + "': expected at most " +
                         std::to_string(kMaxViewBlocks) +
                         " 8^3 blocks in the bounding box, found more");
    for (int a = 0; a < 3; ++a)
        tbl.blocks[static_cast<std::size_t>(a)] =
            static_cast<std::int32_t>(n[static_cast<std::size_t>(a)]);
    const auto count = static_cast<std::size_t>(total);
    auto index = [&](std::int64_t bx, std::int64_t by, std::int64_t bz) {
        return static_cast<std::size_t>((bx * n[1] + by) * n[2] + bz);
    };

    // Pass 1: each block's own 512 values (a leaf buffer, or a constant for tiles/background).
    std::vector<const float*> own(count, nullptr);
    std::vector<float> constant(count, mBackground);  // the value where own[b] is null
    for (std::int64_t bx = 0; bx < n[0]; ++bx)
        for (std::int64_t by = 0; by < n[1]; ++by)
            for (std::int64_t bz = 0; bz < n[2]; ++bz) {
                const openvdb::Coord c(static_cast<openvdb::Int32>(tbl.origin[0] + 8 * bx),
                                       static_cast<openvdb::Int32>(tbl.origin[1] + 8 * by),
                                       static_cast<openvdb::Int32>(tbl.origin[2] + 8 * bz));
                if (const auto* leaf = tree.probeConstLeaf(c))
                    own[index(bx, by, bz)] = leaf->buffer().data();
                else
                    constant[index(bx, by, bz)] = tree.getValue(c);
            }
    auto sameBits = [](float x, float y) { return x == y || (std::isnan(x) && std::isnan(y)); };
    // A block's padded copy is a shared constant when the block and its seven +x/+y/+z
    // neighbours (background past the table) are all the same constant.
    auto constantNeighbourhood = [&](std::int64_t bx, std::int64_t by, std::int64_t bz, float& v) {
        v = own[index(bx, by, bz)] ? 0.0f : constant[index(bx, by, bz)];
        if (own[index(bx, by, bz)]) return false;
        for (int i = 1; i < 8; ++i) {
            const std::int64_t x = bx + ((i >> 2) & 1), y = by + ((i >> 1) & 1), z = bz + (i & 1);
            if (x >= n[0] || y >= n[1] || z >= n[2]) {
                if (!sameBits(v, mBackground)) return false;
                continue;
            }
            if (own[index(x, y, z)] || !sameBits(constant[index(x, y, z)], v)) return false;
        }
        return true;
    };
    std::size_t unique = 0;
    std::vector<float> constants;  // distinct constants of constant neighbourhoods (few)
    auto constantIndex = [&](float v) -> std::size_t {
        for (std::size_t i = 0; i < constants.size(); ++i)
            if (sameBits(constants[i], v)) return i;
        constants.push_back(v);
        return constants.size() - 1;
    };
    for (std::int64_t bx = 0; bx < n[0]; ++bx)
        for (std::int64_t by = 0; by < n[1]; ++by)
            for (std::int64_t bz = 0; bz < n[2]; ++bz) {
                float v;
                if (constantNeighbourhood(bx, by, bz, v))
                    constantIndex(v);
                else
                    ++unique;
            }
    const auto padded = static_cast<std::size_t>(Table::kPadded);
    mPadded.assign((unique + constants.size()) * padded, 0.0f);
    for (std::size_t i = 0; i < constants.size(); ++i)
        std::fill_n(mPadded.data() + (unique + i) * padded, padded, constants[i]);
    tbl.padded = mPadded.data();
    tbl.paddedSize = mPadded.size();
    tbl.data.assign(count, nullptr);
    tbl.maxDilated.assign(count, mBackground);
    tbl.minDilated.assign(count, mBackground);
    auto constantBlock = [&](float v) -> const float* {
        return mPadded.data() + (unique + constantIndex(v)) * padded;
    };
    // Pass 2: the padded copies and their exact value ranges.
    std::size_t next = 0;
    for (std::int64_t bx = 0; bx < n[0]; ++bx)
        for (std::int64_t by = 0; by < n[1]; ++by)
            for (std::int64_t bz = 0; bz < n[2]; ++bz) {
                const std::size_t b = index(bx, by, bz);
                float v;
                if (constantNeighbourhood(bx, by, bz, v)) {
                    tbl.data[b] = constantBlock(v);
                    tbl.minDilated[b] = v;
                    tbl.maxDilated[b] = v;
                    continue;
                }
                float* dst = mPadded.data() + next * static_cast<std::size_t>(Table::kPadded);
                ++next;
                for (int lx = 0; lx < Table::kPad; ++lx)
                    for (int ly = 0; ly < Table::kPad; ++ly)
                        for (int lz = 0; lz < Table::kPad; ++lz) {
                            const std::int64_t x = bx + lx / 8, y = by + ly / 8, z = bz + lz / 8;
                            float value = mBackground;
                            if (x < n[0] && y < n[1] && z < n[2]) {
                                const std::size_t src = index(x, y, z);
                                value = own[src]
                                            ? own[src][((lx % 8) << 6) | ((ly % 8) << 3) | (lz % 8)]
                                            : constant[src];
                            }
                            dst[(lx * Table::kPad + ly) * Table::kPad + lz] = value;
                        }
                const auto [mn, mx] = std::minmax_element(dst, dst + Table::kPadded);
                tbl.data[b] = dst;
                tbl.minDilated[b] = *mn;
                tbl.maxDilated[b] = *mx;
            }
    // Sub-block bounds of every copy (the constant ones included, so that the index of a copy
    // is all a march needs).
    const std::size_t copies = unique + constants.size();
    subBlockBounds(mPadded.data(), copies, mSubMax);
    tbl.subMax = mSubMax.data();
}

float VolumeView::sampleIndex(double x, double y, double z) const noexcept {
    if (mEmpty) return mBackground;
    Cell c;
    const Table& tb = detail::viewTable(*this);
    locate(tb, x, y, z, c);
    return sampleCell(tb, mBackground, c);
}

}  // namespace palp::kernels
