// Ray kernel benchmark: volume bundles vs the OpenVDB baseline, Embree bundles vs raw Embree calls,
// refit costs and batch scaling, each line with both figures and the ratio (see bench/README.md).
// Usage: bench_rays [frames] [real-ct.vdb] [volume]   ("volume": the volume lines only)
#include <cstdio>
#include <cstdlib>
#include <exception>
#include <string>

#include "palp/bench/ray_bench.h"

int main(int argc, char** argv) {
    try {
        using namespace palp::kernels;
        RayBenchOptions o;
        if (argc > 1) o.frames = std::atoi(argv[1]);
        const bool volumeOnly = argc > 3 && std::string(argv[3]) == "volume";
        o.warmUp = std::min(500, o.frames);
        o.batchBundles = std::max(200, std::min(20000, 2 * o.frames));
        RayBenchReport report;
        report.machine = machineDescription();
        if (o.pin) pinMeasuringThread(report);
        auto phantom = makeRayBenchPhantom();
        for (int rays : {17, 25}) {
            o.rays = rays;
            benchVolumeRays(phantom, "phantom", o, report);
        }
        if (argc > 2) {
            openvdb::io::File f(argv[2]);
            f.open();
            auto grid = openvdb::gridPtrCast<openvdb::FloatGrid>(f.getGrids()->front());
            for (int rays : {17, 25}) {
                o.rays = rays;
                benchVolumeRays(grid, "real CT", o, report);
            }
        }
        o.rays = 17;
        if (!volumeOnly) {
            benchMeshRays(o, nullptr, report);
            benchBatchRays(phantom, "phantom", o, report);
        }
        std::printf("machine: %s; measuring thread %s\n", report.machine.c_str(),
                    report.pinned ? "pinned to one core" : "not pinned");
        for (const auto& line : report.lines) std::printf("%s\n", formatComparison(line).c_str());
        return 0;
    } catch (const std::exception& e) {
        std::fprintf(stderr, "bench_rays: error: %s\n", e.what());
        return 1;
    }
}
