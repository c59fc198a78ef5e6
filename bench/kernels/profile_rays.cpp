// Traces the volume bench's bundles with palp's first-hit only (no baseline, no timing), for
// instruction counts under callgrind:
//   valgrind --tool=callgrind --toggle-collect='palp::kernels::traceFirstHit*'
//       build/rays/bench/kernels/profile_rays phantom|FILE.vdb trajectory|random FRAMES [RAYS]
//       [scalar]
// (one command line)
// and prints the number of rays hit (so the work cannot be optimised away).
#include <cstdio>
#include <cstdlib>
#include <exception>
#include <string>

#include "palp/kernels/ray_bench.h"
#include "palp/kernels/volume_ray.h"

int main(int argc, char** argv) {
    try {
        using namespace palp::kernels;
        if (argc < 4) {
            std::fprintf(
                stderr,
                "usage: profile_rays phantom|FILE.vdb trajectory|random FRAMES [RAYS] [scalar]\n");
            return 2;
        }
        const std::string src = argv[1];
        const bool trajectory = std::string(argv[2]) == "trajectory";
        RayBenchOptions o;
        o.frames = std::atoi(argv[3]);
        if (argc > 4) o.rays = std::atoi(argv[4]);
        openvdb::FloatGrid::Ptr grid;
        if (src == "phantom") {
            grid = makeRayBenchPhantom();
        } else {
            openvdb::initialize();
            openvdb::io::File f(src);
            f.open();
            grid = openvdb::gridPtrCast<openvdb::FloatGrid>(f.getGrids()->front());
        }
        const auto bundles = volumeBenchBundles(*grid, src == "phantom", trajectory, o);
        const VolumeView view(grid);
        FirstHitParams fp;
        fp.threshold = o.threshold;
        fp.step = o.step;
        fp.simd = !(argc > 5 && std::string(argv[5]) == "scalar");
        BundleHits hits;
        long hitCount = 0;
        for (const auto& b : bundles) {
            traceFirstHit(view, b, fp, hits);
            for (int r = 0; r < hits.count; ++r) hitCount += hits.hit[static_cast<std::size_t>(r)];
        }
        std::printf("%zu bundles, %ld rays hit\n", bundles.size(), hitCount);
        return 0;
    } catch (const std::exception& e) {
        std::fprintf(stderr, "profile_rays: error: %s\n", e.what());
        return 1;
    }
}
