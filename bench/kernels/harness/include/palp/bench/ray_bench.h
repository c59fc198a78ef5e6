#pragma once
/// @file
/// The ray benchmark behind `palp bench rays` and bench/kernels/bench_rays: per-frame cost of
/// AVC/AVCEC bundles through volumes and Embree meshes, each next to a baseline measured in the
/// same run (BENCHMARKS.md). Part of the benchmark harness (library palp_ray_bench under
/// bench/kernels/harness), not of palp::kernels.

#include <openvdb/openvdb.h>

#include <cstdint>
#include <string>
#include <vector>

#include "palp/kernels/ray_bundle.h"
#include "palp/kernels/triangle_mesh.h"

namespace palp::kernels {

/// What to measure.
struct RayBenchOptions {
    int rays = 17;             ///< rays per bundle: 17 (no ring) or 17 + ring count, at most 64
    int frames = 10000;        ///< measured frames per figure (after warmUp)
    int warmUp = 500;          ///< frames run before measuring
    double length = 10e-3;     ///< ray length, metres
    double step = 0.25e-3;     ///< sample spacing, metres
    float threshold = 300;     ///< first-hit threshold (HU for CT)
    int batchBundles = 20000;  ///< bundles per batch-throughput run
    bool pin = true;           ///< pin the measuring thread to one core
    /// Volume lines: also time palp and the baseline in blocks of this many frames each (warm
    /// caches, as a servo thread owning its core); <= 1 skips that line.
    int warmBlockFrames = 250;
    std::uint64_t seed = 1;
};

/// Per-frame (or per-call) timing figures in microseconds.
struct TimingStats {
    double meanUs = 0, p99Us = 0, maxUs = 0;  ///< wall clock per frame
    double cpuMeanUs = 0;  ///< thread CPU time per frame (excludes preemption), 0 when not measured
    /// p99 of the per-frame thread CPU time (the clock's read cost subtracted; its resolution
    /// is the kernel's, about 1 us or better), 0 when not measured. Unlike the wall p99 it does
    /// not count preemption, so it is the p99 to compare on a loaded machine.
    double cpuP99Us = 0;
    std::size_t samples = 0;
};

/// One comparison line: subject against baseline measured in the same run.
struct BenchComparison {
    std::string name;         ///< e.g. "volume 17 rays, phantom, trajectory"
    std::string subject;      ///< e.g. "palp"
    std::string baseline;     ///< e.g. "OpenVDB baseline"
    TimingStats a, b;         ///< subject, baseline
    double ratioMean = 0;     ///< b.mean / a.mean (> 1: subject faster)
    double ratioP99 = 0;      ///< b.p99 / a.p99
    std::string unit = "us";  ///< "us" per frame, or "Mrays/s" (then only meanUs is used)
    std::string note;         ///< agreement check, frames per 1 ms, ...
};

/// All lines of a run plus the machine it ran on.
struct RayBenchReport {
    std::string machine;  ///< CPU model and core count
    bool pinned = false;  ///< whether pinning the measuring thread succeeded
    /// The CPUs the measuring thread had before pinMeasuringThread() (empty when it was not
    /// called): the batch line runs on them, as a thread pool would.
    std::vector<int> unpinnedCpus;
    std::vector<BenchComparison> lines;
};

/// The built-in phantom: a 60 x 60 x 30 mm box of soft tissue (40 HU) holding a 4 mm bone plate
/// (1000 HU) 8 mm below its top face, in a -1000 HU inactive background, at @p voxelSize.
openvdb::FloatGrid::Ptr makeRayBenchPhantom(double voxelSize = 0.5e-3);

/// Volume bundles (trajectory and random positions) against the OpenVDB baseline
/// (VolumeRayIntersector spans sampled with BoxSampler through a ValueAccessor, fixed step).
/// Appends lines labelled with @p label. @throw palp::ValueError for an unusable grid/options.
void benchVolumeRays(const openvdb::FloatGrid::ConstPtr& grid, const std::string& label,
                     const RayBenchOptions& options, RayBenchReport& report);

/// Embree bundles against 2k and 32k triangle height fields (and @p userMesh when not null)
/// next to a raw rtcIntersect1 loop and rtcIntersect1M coherent; refit costs of deforming 2k
/// and 32k meshes.
void benchMeshRays(const RayBenchOptions& options, const TriangleMesh* userMesh,
                   RayBenchReport& report);

/// Batch throughput (rays per second) of traceFirstHitBatch with 1 thread and all threads.
void benchBatchRays(const openvdb::FloatGrid::ConstPtr& grid, const std::string& label,
                    const RayBenchOptions& options, RayBenchReport& report);

/// The bundles one volume line measures, for profiling outside the harness: @p trajectory picks
/// the Lissajous proxy path (1 mm under the top face when @p phantom, else through the middle of
/// the active box), otherwise uniform random positions and directions in the active box.
/// @throw palp::ValueError for unusable options (rays outside 17..64, frames < 1).
std::vector<RayBundle> volumeBenchBundles(const openvdb::FloatGrid& grid, bool phantom,
                                          bool trajectory, const RayBenchOptions& options);

/// Pins the calling thread to the last allowed CPU; false when not possible.
bool pinCurrentThread() noexcept;

/// pinCurrentThread() for a run measured into @p report: remembers the thread's CPUs from
/// before the pin in report.unpinnedCpus (benchBatchRays() runs on them) and sets
/// report.pinned. @return report.pinned.
bool pinMeasuringThread(RayBenchReport& report);

/// CPU model and `nproc`.
std::string machineDescription();

/// One line: "<name>: <subject> a mean / p99 / max us; <baseline> ... ; rmean x / rp99 x".
std::string formatComparison(const BenchComparison& c);

}  // namespace palp::kernels
