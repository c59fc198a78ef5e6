#pragma once
/// @file
/// Ray marching through a FloatGrid for AVC/AVCEC: first-hit (threshold crossing) and
/// accumulate (integral of a transfer function) modes, for single rays and whole bundles.
///
/// The grid is read through a VolumeView: a flat table of the grid's 8^3 blocks built once at
/// set-up, each stored as a 9^3 copy that includes the first voxel layer of its +x/+y/+z
/// neighbours. Every cell whose base voxel lies in a block then finds its eight corners in that
/// one copy: a trilinear sample costs one table load and eight float loads with no branch on
/// the position in the block, instead of a tree walk through a ValueAccessor. Blocks whose
/// values cannot matter (the maximum of their 9^3 copy is below the threshold, or the transfer
/// function is zero there) are skipped with a 3D DDA over the block grid, without sampling; in
/// the blocks that remain, first-hit also jumps over the 4^3 sub-blocks whose bound is below
/// the threshold.
/// Skipping never changes a result: samples stay on the lattice t_k = k * step.
///
/// First-hit's fast path takes a HitField built at set-up for the threshold (a bit per cell that
/// can reach it, and per-block distances to the blocks that have one) and marches each ray's
/// samples eight at a time; it agrees with the block-run path to float rounding (see HitField).
/// Applications that trace first-hit bundles every servo tick should build one (haptics::Session
/// does).

#include <openvdb/openvdb.h>

#include <Eigen/Core>
#include <array>
#include <cstdint>
#include <memory>
#include <span>
#include <vector>

#include "palp/kernels/ray_bundle.h"

namespace palp::kernels {

/// Largest number of samples one ray takes (bounds the time of a ray of any length).
inline constexpr std::int64_t kMaxSamplesPerRay = std::int64_t{1} << 16;
/// Largest number of 8^3 blocks a VolumeView accepts (its table costs 16 bytes per block).
inline constexpr std::int64_t kMaxViewBlocks = std::int64_t{1} << 26;

/// Read-only flat view of a FloatGrid for ray marching. Holds a shared pointer to the grid and a
/// padded copy of its values (about 1.4x the leaf data, plus one shared copy per distinct
/// constant); changes to the grid after construction are not seen.
///
/// @par Threading  Immutable after construction: any number of threads may trace through one
///      view at the same time, with no per-thread state.
/// @par Real-time  Construction allocates and is for set-up threads; sampling and tracing are
///      noexcept and allocation-free.
class VolumeView {
  public:
    /// Builds the block table over the bounding box of @p grid's leaves and active tiles, grown
    /// by one block on each side, and the padded 9^3 copies. Forces delay-loaded leaf buffers
    /// into memory.
    /// @throw palp::ValueError for a null grid, a transform that is not an axis-aligned
    ///        isotropic scale plus translation, or a table above kMaxViewBlocks blocks.
    explicit VolumeView(openvdb::FloatGrid::ConstPtr grid);
    /// Not copyable: the block table points into this object's own buffer.
    VolumeView(const VolumeView&) = delete;
    VolumeView& operator=(const VolumeView&) = delete;

    /// Trilinear value at index position (x, y, z) (voxel centres at integers); background
    /// outside the table. Bit-compatible with sampleIndex() through an accessor (same weights,
    /// evaluated in float here).
    /// @par Real-time  noexcept, no allocation.
    float sampleIndex(double x, double y, double z) const noexcept;

    /// Voxel edge length, metres.
    double voxelSize() const noexcept { return mVoxelSize; }
    /// 1 / voxelSize(), per metre.
    double inverseVoxelSize() const noexcept { return mInvVoxelSize; }
    float background() const noexcept { return mBackground; }
    const openvdb::FloatGrid& grid() const noexcept { return *mGrid; }
    /// True when the grid has no leaves and no active tiles.
    bool empty() const noexcept { return mEmpty; }
    /// World position (metres) -> index position.
    Eigen::Vector3d indexFromWorld(const Eigen::Vector3d& w) const noexcept {
        return (w - mWorldOrigin) * mInvVoxelSize;
    }
    /// World position (metres) of index position (0, 0, 0).
    const Eigen::Vector3d& worldOrigin() const noexcept { return mWorldOrigin; }

    // Internal layout, read by the marcher (kept public for the kernels' free functions).
    struct Table {
        static constexpr int kPad = 9;  ///< padded block edge (8 own voxels + 1 halo)
        static constexpr int kPadded = kPad * kPad * kPad;
        std::array<std::int32_t, 3> origin{};  ///< index of the first voxel (multiple of 8)
        std::array<std::int32_t, 3> blocks{};  ///< blocks per axis
        /// Per block: kPadded values, x-major ((lx * 9 + ly) * 9 + lz), lx, ly, lz in 0..8; the
        /// layer 8 holds the neighbour block's layer 0 (background past the table).
        std::vector<const float*> data;
        std::vector<float> maxDilated;  ///< max over the block's padded copy
        std::vector<float> minDilated;  ///< min over the same
        /// Every padded copy (constant ones included) lies in one buffer starting here, so a
        /// gather can address any block's values with 32-bit offsets from this base.
        const float* padded = nullptr;
        std::size_t paddedSize = 0;  ///< floats in that buffer
        /// Per padded copy c (the one at padded + c * kPadded), 8 floats: for each 4^3 sub-block
        /// s = 4 (lx >> 2) + 2 (ly >> 2) + (lz >> 2) of the cells based in the block, an upper
        /// bound on every value a first-hit sample in those cells can take (the maximum of the
        /// sub-block's 5^3 corner values, raised by a hair for the rounding of the trilinear
        /// blend and for positions a rounding step outside the cell). A sample there can only
        /// reach a threshold above the bound, so the march skips such sub-blocks in a block it
        /// cannot skip whole.
        const float* subMax = nullptr;
        static constexpr int kSubBlocks = 8;
    };
    const Table& table() const noexcept { return mTable; }

  private:
    openvdb::FloatGrid::ConstPtr mGrid;
    Table mTable;
    /// Padded copies of the blocks that are not constant, then one shared copy per distinct
    /// constant.
    std::vector<float> mPadded;
    std::vector<float> mSubMax;  ///< Table::subMax
    Eigen::Vector3d mWorldOrigin = Eigen::Vector3d::Zero();
    double mVoxelSize = 1;
    double mInvVoxelSize = 1;
    float mBackground = 0;
    bool mEmpty = true;
};

/// First-hit acceleration for one threshold (the fast path of firstHit() and traceFirstHit()).
/// It holds, for every padded block copy of a VolumeView that can reach the threshold, one bit
/// per cell: set when the cell's trilinear values can reach it (its corner maximum, raised by the
/// same hair as the 4^3 sub-block bounds); and for every table block one 32-bit entry with the
/// index of its copy's mask and the Chebyshev distance in blocks (at most kFarBlocks) to the
/// nearest block that has such a cell.
///
/// With a field the march takes the ray's samples on one float lattice in table coordinates
/// (not re-anchored per block), eight at a time with AVX2: the cells, blocks and mask bits of
/// eight samples in one step, the blend only at samples in cells that can reach the threshold,
/// and a jump over the samples that stay among blocks with none. Rays through soft tissue next
/// to bone cost a few vector steps instead of a block entry per 8^3 block and a blend per half
/// voxel. The samples are the same lattice samples as without a field at positions within
/// about 5e-4 voxel, so hits agree with the block-run path to that rounding, not bit for bit
/// (tests: the same hits and t within 1e-3 voxel on the bone-slab volume; on the 0.5 mm head CT,
/// 840,000 bench rays with no hit/miss difference and t within 3e-3 voxel, where grazing rays
/// amplify position rounding). With a field, scalar and AVX2, bundle and single ray give the
/// same bits.
///
/// Built at set-up, off the servo thread: 64 bytes (one cache line) per block copy that can
/// reach the threshold and 4 bytes per table block (`palp bench rays` prints the size and the
/// build time). A threshold change needs a new field, and a march whose threshold differs from
/// the field's ignores it.
///
/// @par Threading  Immutable after construction; any number of threads may trace with it.
///      The view must outlive the field.
/// @par Real-time  Construction allocates (set-up only); reading is noexcept.
class HitField {
  public:
    /// @throw palp::ValueError for a NaN threshold, or more block copies than the 27-bit mask
    ///        index holds.
    HitField(const VolumeView& view, float threshold);
    HitField(const HitField&) = delete;
    HitField& operator=(const HitField&) = delete;

    float threshold() const noexcept { return mThreshold; }
    const VolumeView& view() const noexcept { return *mView; }
    /// True when a first-hit march through @p view at @p threshold can use this field.
    bool matches(const VolumeView& view, float threshold) const noexcept {
        return &view == mView && threshold == mThreshold;
    }
    /// Heap bytes held.
    std::size_t bytes() const noexcept {
        return mMask.capacity() * sizeof(MaskLine) + mEntry.capacity() * sizeof(std::uint32_t) +
               mCopy.capacity() * sizeof(const float*) +
               mCopyOffset.capacity() * sizeof(std::int32_t);
    }
    /// Block copies that have at least one cell that can reach the threshold.
    std::size_t hotCopies() const noexcept { return mHotCopies; }

    // Internal layout, read by the marcher.
    static constexpr int kCells = 512;
    static constexpr int kMaskWords = kCells / 32;  ///< 16 words: one 64-byte cache line
    static constexpr std::uint8_t kFarBlocks = 16;
    static constexpr int kDistanceBits = 5;  ///< low bits of an entry: the block distance
    /// Table block @p block's entry: (mask index << kDistanceBits) | block distance. Mask 0 is
    /// all clear (the blocks with no cell that can reach the threshold share it).
    std::uint32_t entry(std::size_t block) const noexcept { return mEntry[block]; }
    /// 0 when the block has a cell that can reach the threshold, else the Chebyshev distance in
    /// blocks to the nearest block that has one (at most kFarBlocks): the (2D - 1)^3 blocks
    /// around a block at distance D hold no such cell.
    unsigned blockDistance(std::size_t block) const noexcept {
        return mEntry[block] & ((1u << kDistanceBits) - 1u);
    }
    /// The 16-word mask of table block @p block's copy: cell (x, y, z), local index
    /// l = (x * 8 + y) * 8 + z, is bit l % 32 of word l / 32.
    const std::uint32_t* blockMask(std::size_t block) const noexcept {
        return mMask[mEntry[block] >> kDistanceBits].w;
    }
    /// True when cell @p local (as in blockMask()) of table block @p block can reach the
    /// threshold.
    bool cellCanReach(std::size_t block, unsigned local) const noexcept {
        return ((blockMask(block)[local >> 5] >> (local & 31u)) & 1u) != 0;
    }
    /// The padded block copy (as VolumeView::Table::data) of mask index @p mask > 0: a small
    /// array (8 bytes per copy that can reach the threshold) that stays cached where the table's
    /// pointers (8 bytes per table block) would miss.
    const float* maskCopy(std::uint32_t mask) const noexcept { return mCopy[mask]; }
    /// The same as an offset in floats from VolumeView::Table::padded (mask 0: 0), for gathers;
    /// valid when the padded buffer has fewer than 2^31 - 1024 floats.
    const std::int32_t* maskCopyOffsets() const noexcept { return mCopyOffset.data(); }
    /// maskCopy() of every mask index, as an array (for prefetching).
    const float* const* maskCopies() const noexcept { return mCopy.data(); }
    /// True when maskCopyOffsets() holds the offsets (the padded buffer has fewer than
    /// 2^31 - 1024 floats, so 32-bit gathers reach every copy); else they are all 0.
    bool copyOffsetsValid() const noexcept { return mCopyOffsetsValid; }
    /// The entries (per table block) and the masks (16 words per mask index), for gathers.
    const std::uint32_t* entries() const noexcept { return mEntry.data(); }
    const std::uint32_t* masks() const noexcept { return mMask.front().w; }

  private:
    struct alignas(64) MaskLine {
        std::uint32_t w[kMaskWords];
    };
    const VolumeView* mView;
    float mThreshold;
    std::vector<std::uint32_t> mEntry;      ///< per table block: entry()
    std::vector<MaskLine> mMask;            ///< per mask index (0: all clear)
    std::vector<const float*> mCopy;        ///< per mask index: maskCopy()
    std::vector<std::int32_t> mCopyOffset;  ///< per mask index: maskCopyOffsets()
    bool mCopyOffsetsValid = false;
    std::size_t mHotCopies = 0;
};

/// Hardness transfer function sigma(value) >= 0 (per metre), piecewise linear through up to
/// kMaxNodes nodes (value, sigma) with non-decreasing values; two nodes with the same value make
/// a step. Constant beyond the end nodes.
/// @par Threading  A plain value.
class TransferFunction {
  public:
    static constexpr int kMaxNodes = 16;
    TransferFunction() = default;
    /// @throw palp::ValueError for no node, more than kMaxNodes, decreasing values, negative or
    ///        non-finite sigma.
    explicit TransferFunction(std::span<const std::array<float, 2>> nodes);
    /// sigma = 0 below @p threshold and @p height (1/m) from it on.
    static TransferFunction step(float threshold, float height);

    /// sigma(v), per metre. @par Real-time noexcept.
    float sigma(float v) const noexcept;
    /// An antiderivative S(v) = integral of sigma dv (per metre times value units).
    /// @par Real-time noexcept.
    double integral(double v) const noexcept;
    /// sigma(u) == 0 for every u < zeroBelow() (-inf when sigma is positive everywhere).
    float zeroBelow() const noexcept { return mZeroBelow; }

  private:
    std::array<float, kMaxNodes> mV{}, mS{};
    std::array<double, kMaxNodes> mCum{};  // S at each node
    int mCount = 0;
    float mZeroBelow = 0;
};

/// First-hit settings.
struct FirstHitParams {
    float threshold = 300;  ///< hit where the interpolated value first reaches this (value units)
    double step = 0.25e-3;  ///< sample spacing along the ray, metres
    int refineIterations = 2;  ///< regula-falsi steps below the step size (0: linear interpolation)
    bool skipEmpty = true;     ///< skip blocks whose dilated maximum is below the threshold
    /// traceFirstHit() only: march the rays of a bundle eight at a time in lockstep with AVX2
    /// where the CPU has it (bundleSimdAvailable()). The results are bit-identical to the scalar
    /// path (false), which stays the reference and the fallback.
    bool simd = true;
    /// Optional first-hit acceleration for this threshold (see HitField), used when
    /// field->matches(view, threshold), skipEmpty, a background below the threshold and a
    /// table of at most 1024 blocks per axis; otherwise ignored. Changes results only by float
    /// rounding (HitField).
    const HitField* field = nullptr;
};

/// Accumulate settings.
struct AccumulateParams {
    TransferFunction sigma;       ///< hardness per metre as a function of value
    double tauStop = 1;           ///< stop where the integral of sigma reaches this (dimensionless)
    double step = 0.25e-3;        ///< sample spacing, metres
    bool reportFirstHit = false;  ///< also find the first crossing of firstHitThreshold
    float firstHitThreshold = 300;
    bool skipEmpty = true;  ///< skip blocks where sigma is zero (and no crossing is possible)
};

/// Result of one first-hit ray.
struct RayHit {
    float t = 0;  ///< metres along the unit direction; the ray length when there is no hit
    bool hit = false;
};

/// Result of one accumulate ray.
struct AccumulateHit {
    float t = 0;           ///< where the integral reached tauStop, or the ray length (metres)
    float integral = 0;    ///< integral of sigma up to t (dimensionless)
    float firstHitT = 0;   ///< first crossing (when reportFirstHit and firstHit), metres
    bool stopped = false;  ///< integral reached tauStop
    bool firstHit = false;
};

/// Per-ray results of a bundle, same order as RayBundle. Rays beyond `count` are untouched.
/// @par Real-time  Fixed capacity.
struct BundleHits {
    std::array<float, kMaxBundleRays> t{};               ///< metres (ray length when no hit)
    std::array<std::uint8_t, kMaxBundleRays> hit{};      ///< 1 = hit
    std::array<std::uint32_t, kMaxBundleRays> geomId{};  ///< mesh traces: Embree geometry id
    int count = 0;
};

/// Per-ray accumulate results of a bundle.
struct BundleAccumulation {
    std::array<float, kMaxBundleRays> t{}, integral{}, firstHitT{};
    std::array<std::uint8_t, kMaxBundleRays> stopped{}, firstHit{};
    int count = 0;
};

/// Marches one ray from @p origin (world metres) along @p direction (normalised here) for
/// @p length metres, sampling at t_k = min(k step, length), and returns the first t where the
/// trilinear value is >= threshold, refined between the bracketing samples (linear
/// interpolation, then params.refineIterations regula-falsi steps on the true trilinear
/// curve; between two samples of one block run the probes are blended at the run's float
/// positions, see below). A start inside (value >= threshold at t = 0) hits at t = 0.
/// Degenerate input (zero or non-finite direction or origin, non-finite or negative length, a
/// non-positive step, an empty grid) gives {t = max(length, 0) or 0, hit = false}.
/// Time is bounded by kMaxSamplesPerRay samples (longer rays are cut there).
/// Inside a block the march places sample i of a run at q + float(i) s in single precision,
/// from the exact (double) block-local position q of the run's first sample, so a sample sits
/// within about 1e-5 voxel of o + t_k d and its value does not depend on which samples were
/// taken before it. Runs start at the same samples with and without skipping, and skipped
/// blocks and 4^3 sub-blocks hold only values below the threshold, so params.skipEmpty never
/// changes the result (bit for bit).
/// @par Threading  Any number of threads on one view.
/// @par Real-time  noexcept, no allocation, no lock.
RayHit firstHit(const VolumeView& view, const Eigen::Vector3d& origin,
                const Eigen::Vector3d& direction, double length,
                const FirstHitParams& params) noexcept;

/// Integrates tau(t) = integral_0^t sigma(v(s)) ds along the ray (v linear between samples, so
/// each step's integral is exact for a piecewise-linear sigma) and returns the t where tau
/// reaches tauStop (or the length), tau there, and optionally the first crossing. Same
/// degenerate-input rules and bounds as firstHit().
/// @par Threading  Any number of threads on one view.
/// @par Real-time  noexcept, no allocation, no lock.
AccumulateHit accumulate(const VolumeView& view, const Eigen::Vector3d& origin,
                         const Eigen::Vector3d& direction, double length,
                         const AccumulateParams& params) noexcept;

/// First-hit for every ray of @p bundle (an invalid bundle gives count = 0). Each result is
/// bit-identical to firstHit() on that ray with the same params. The bundle's hits are refined
/// together after the march (the refinement chains of different rays overlap in the CPU), and
/// the table entries and block copies along the first ray are prefetched before it (the other
/// rays leave from the same proxy within a few degrees). With params.field (the fast path, see
/// HitField) each ray is marched on its lattice, eight samples at a time with params.simd on a
/// CPU with AVX2. Without a field, params.simd marches the rays eight at a time in lockstep
/// through their non-skippable blocks (one gather of the cell corners per lane and sample);
/// skipping, block entries and the refinement stay scalar.
/// @par Threading  Any number of threads on one view, each with its own @p out.
/// @par Real-time  noexcept, no allocation, no lock; bounded by count * kMaxSamplesPerRay.
void traceFirstHit(const VolumeView& view, const RayBundle& bundle, const FirstHitParams& params,
                   BundleHits& out) noexcept;

/// True when traceFirstHit() can take its AVX2 lockstep path on this CPU (x86-64 with AVX2, a
/// GCC or Clang build). @par Real-time noexcept.
bool bundleSimdAvailable() noexcept;

/// Accumulate for every ray of @p bundle.
/// @par Threading  Any number of threads on one view, each with its own @p out.
/// @par Real-time  noexcept, no allocation, no lock.
void traceAccumulate(const VolumeView& view, const RayBundle& bundle,
                     const AccumulateParams& params, BundleAccumulation& out) noexcept;

/// Throws palp::ValueError when @p params cannot be used (non-positive or non-finite step,
/// NaN threshold, negative refine count). Call at set-up; the kernels themselves never throw.
void validateFirstHitParams(const FirstHitParams& params);
/// Same for accumulate (also tauStop > 0 and finite).
void validateAccumulateParams(const AccumulateParams& params);

}  // namespace palp::kernels
