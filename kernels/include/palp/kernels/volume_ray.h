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

#include <Eigen/Core>
#include <array>
#include <cstdint>
#include <memory>
#include <span>
#include <vector>

#include "palp/kernels/hit_field.h"
#include "palp/kernels/ray_bundle.h"
#include "palp/kernels/transfer_function.h"
#include "palp/kernels/volume_view.h"

namespace palp::kernels {

/// Largest number of samples one ray takes (bounds the time of a ray of any length).
inline constexpr std::int64_t kMaxSamplesPerRay = std::int64_t{1} << 16;

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
