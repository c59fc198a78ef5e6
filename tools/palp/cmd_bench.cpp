// palp bench rays: how many AVC/AVCEC ray bundles fit in a haptic frame on this machine and data,
// each figure next to a baseline measured in the same run.
#include <cstdio>
#include <filesystem>
#include <memory>
#include <nlohmann/json.hpp>
#include <string>

#include "commands.h"
#include "option_checks.h"
#include "palp/base/error.h"
#include "palp/bench/ray_bench.h"
#include "palp/volume/load.h"
#include "palp/volume/mesh.h"

namespace palp::tool {

namespace fs = std::filesystem;
using nlohmann::json;

namespace {

json stats(const kernels::TimingStats& s, const std::string& unit) {
    if (unit == "Mrays/s") return {{"mrays_per_s", s.meanUs}};
    return {{"mean_us", s.meanUs},        {"p99_us", s.p99Us},        {"max_us", s.maxUs},
            {"cpu_mean_us", s.cpuMeanUs}, {"cpu_p99_us", s.cpuP99Us}, {"frames", s.samples}};
}

}  // namespace

Command addBench(CLI::App& root) {
    struct Args {
        std::string volume;
        std::string mesh;
        double meshUnit = 1e-3;
        double voxelMm = 0;
        int rays = 0;
        int frames = 10000;
        int warmBlock = 250;
        float threshold = 300;
        bool json = false;
        bool noPin = false;
        bool noBatch = false;
    };
    auto args = std::make_shared<Args>();
    CLI::App* bench = root.add_subcommand("bench", "Measure palp's kernels on this machine");
    bench->require_subcommand(1);
    CLI::App* app = bench->add_subcommand("rays",
                                          "Per-frame cost of AVC/AVCEC ray bundles (volume and "
                                          "Embree) against baselines in the same run");
    app->add_option("--volume", args->volume,
                    "A .vdb (or any scan palp reads); default: the built-in phantom");
    app->add_option("--voxel", args->voxelMm,
                    "Resample --volume to this voxel size, mm (default: as stored)")
        ->check(within(bounds::kSpacing, kMm));
    app->add_option("--mesh", args->mesh,
                    "A triangle mesh (OBJ, STL, PLY) to trace next to the built-in meshes");
    app->add_option("--mesh-unit", args->meshUnit,
                    "Metres per mesh file unit (default 1e-3: millimetres)")
        ->check(within(bounds::kMeshUnit));
    app->add_option("--rays", args->rays, "Rays per bundle, 17..64 (17 + ring); default: 17 and 25")
        ->check(integerIn(17, 64));
    app->add_option("--frames", args->frames, "Measured frames per figure")
        ->check(integerIn(10, 10000000));
    app->add_option("--threshold", args->threshold, "First-hit threshold (HU for CT), default 300")
        ->check(within(bounds::kVolumeValue));
    app->add_option("--warm-block", args->warmBlock,
                    "Volume: also time palp and the baseline in blocks of this many frames each "
                    "(warm caches, as a servo thread owning its core); 0: skip (default 250)")
        ->check(integerIn(0, 100000));
    app->add_flag("--json", args->json, "Print the figures as JSON");
    app->add_flag("--no-pin", args->noPin, "Do not pin the measuring thread to one core");
    app->add_flag("--no-batch", args->noBatch, "Skip the batch-throughput figures");
    const Command servo = addBenchServo(*bench);
    const Command tick = addBenchTick(*bench);

    return {bench, [args, servo, tick]() -> int {
                if (servo.app->parsed()) return servo.run();
                if (tick.app->parsed()) return tick.run();
                kernels::RayBenchOptions o;
                o.frames = args->frames;
                o.warmUp = std::min(500, args->frames);
                o.threshold = args->threshold;
                o.warmBlockFrames = args->warmBlock;
                o.batchBundles = std::max(200, std::min(20000, 2 * args->frames));
                kernels::RayBenchReport report;
                report.machine = kernels::machineDescription();
                std::string label = "phantom";
                openvdb::FloatGrid::Ptr grid;
                if (!args->volume.empty()) {
                    volume::LoadOptions lo;
                    if (args->voxelMm > 0) lo.resample.voxelSize = args->voxelMm * 1e-3;
                    volume::Volume v = volume::load({fs::path(args->volume)}, lo);
                    grid = v.grid;
                    label = fs::path(args->volume).filename().string();
                } else {
                    grid = kernels::makeRayBenchPhantom(0.5e-3);
                }
                std::unique_ptr<kernels::TriangleMesh> mesh;
                if (!args->mesh.empty())
                    mesh = std::make_unique<kernels::TriangleMesh>(
                        volume::loadMesh(args->mesh, args->meshUnit));
                if (!args->noPin) kernels::pinMeasuringThread(report);
                if (!globals().quiet && !args->json)
                    std::fprintf(stderr, "palp: measuring %d frames per figure...\n", o.frames);
                const std::vector<int> rayCounts =
                    args->rays ? std::vector<int>{args->rays} : std::vector<int>{17, 25};
                for (int r : rayCounts) {
                    o.rays = r;
                    kernels::benchVolumeRays(grid, label, o, report);
                }
                o.rays = rayCounts.front();
                kernels::benchMeshRays(o, mesh.get(), report);
                if (!args->noBatch) kernels::benchBatchRays(grid, label, o, report);
                if (args->json) {
                    json j;
                    j["machine"] = report.machine;
                    j["pinned"] = report.pinned;
                    j["frames"] = o.frames;
                    j["ray_length_mm"] = o.length * 1e3;
                    j["step_mm"] = o.step * 1e3;
                    j["lines"] = json::array();
                    for (const auto& l : report.lines)
                        j["lines"].push_back({{"name", l.name},
                                              {"subject", l.subject},
                                              {"baseline", l.baseline},
                                              {"unit", l.unit},
                                              {"subject_figures", stats(l.a, l.unit)},
                                              {"baseline_figures", stats(l.b, l.unit)},
                                              {"ratio_mean", l.ratioMean},
                                              {"ratio_p99", l.ratioP99},
                                              {"note", l.note}});
                    std::printf("%s\n", j.dump(2).c_str());
                } else {
                    std::printf("machine: %s; measuring thread %s; rays %.0f mm at %.2f mm steps\n",
                                report.machine.c_str(),
                                report.pinned ? "pinned to one core" : "not pinned", o.length * 1e3,
                                o.step * 1e3);
                    for (const auto& l : report.lines)
                        std::printf("%s\n", kernels::formatComparison(l).c_str());
                }
                return 0;
            }};
}

}  // namespace palp::tool
