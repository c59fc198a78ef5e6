// Where `palp convert` spends its time: reading the slices, resampling, writing the .vdb with
// each compression; on an input palp reads, or on a generated tilted CT-like series (made in
// memory by tests/support/tilted_series.h: 0.5 mm pixels, 0.5 mm gaps, 12 degree tilt).
//   bench_convert INPUT VOXEL_MM [REPEATS]
//   bench_convert --generate COLS ROWS SLICES [REPEATS]
//   bench_convert --write-dicom DIR COLS ROWS SLICES   (the generated series as DICOM files)
// Prints the median of REPEATS (default 3) of each phase, the grid's memory and active voxels;
// for an input, also load() (reading and resampling as palp convert runs them: a DICOM series
// decoded in bands as the resampler reaches it).
#include <sys/resource.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <string>
#include <vector>

#include "palp/volume/dicom.h"
#include "palp/volume/load.h"
#include "palp/volume/resample.h"
#include "tilted_series.h"

namespace {

namespace fs = std::filesystem;
using Clock = std::chrono::steady_clock;

double median(std::vector<double> v) {
    std::sort(v.begin(), v.end());
    return v.size() % 2 ? v[v.size() / 2] : 0.5 * (v[v.size() / 2 - 1] + v[v.size() / 2]);
}

double cpuSeconds() {
    rusage u{};
    getrusage(RUSAGE_SELF, &u);
    return static_cast<double>(u.ru_utime.tv_sec + u.ru_stime.tv_sec) +
           1e-6 * static_cast<double>(u.ru_utime.tv_usec + u.ru_stime.tv_usec);
}

/// Wall seconds of f(); adds its CPU seconds (all threads, user + system) to @p cpu.
template <class F>
double seconds(F&& f, std::vector<double>* cpu = nullptr) {
    const double c0 = cpuSeconds();
    const auto t0 = Clock::now();
    f();
    const double wall = std::chrono::duration<double>(Clock::now() - t0).count();
    if (cpu) cpu->push_back(cpuSeconds() - c0);
    return wall;
}

palp::volume::SliceStack generated(char** dims) {
    return palp::test::tiltedSeries(std::atoi(dims[0]), std::atoi(dims[1]), std::atoi(dims[2]),
                                    0.0005, 0.0005, 12.0);
}

}  // namespace

int main(int argc, char** argv) {
    using namespace palp::volume;
    const std::string mode = argc > 1 ? argv[1] : "";
    if (argc < 3 || ((mode == "--generate" && argc < 5) || (mode == "--write-dicom" && argc < 6))) {
        std::fprintf(stderr,
                     "usage: bench_convert INPUT VOXEL_MM [REPEATS]\n"
                     "       bench_convert --generate COLS ROWS SLICES [REPEATS]\n"
                     "       bench_convert --write-dicom DIR COLS ROWS SLICES\n");
        return 2;
    }
    initialize();
    if (mode == "--write-dicom") {
        DicomWriteOptions wo;
        wo.gantryTiltDeg = 12;
        wo.seriesDescription = "palp bench tilted series";
        writeDicomSeries(generated(argv + 3), argv[2], wo);
        return 0;
    }
    const bool gen = mode == "--generate";
    const int repeatArg = gen ? 5 : 3;
    const int repeats = argc > repeatArg ? std::max(1, std::atoi(argv[repeatArg])) : 3;
    ResampleOptions ro;
    if (!gen) ro.voxelSize = std::atof(argv[2]) * 1e-3;
    std::vector<double> tRead, tResample, tBlosc, tMask, tZip, cRead, cResample, cBlosc, cMask;
    std::vector<double> tLoad, cLoad;  // load(): what palp convert runs, slices decoded in bands
    Volume vol;
    SliceStack stack;
    for (int r = 0; r < repeats; ++r) {
        tRead.push_back(
            seconds([&] { stack = gen ? generated(argv + 2) : readStack({fs::path(argv[1])}, {}); },
                    &cRead));
        vol = {};
        tResample.push_back(seconds([&] { vol = resample(stack, ro); }, &cResample));
        if (!gen) {
            LoadOptions lo;
            lo.resample = ro;
            vol = {};
            tLoad.push_back(seconds([&] { vol = load({fs::path(argv[1])}, lo); }, &cLoad));
        }
        const fs::path out = fs::temp_directory_path() / "palp_bench_convert.vdb";
        tBlosc.push_back(seconds([&] { save(vol, out, {Compression::Blosc}); }, &cBlosc));
        tMask.push_back(seconds([&] { save(vol, out, {Compression::ActiveMask}); }, &cMask));
        if (r == 0) tZip.push_back(seconds([&] { save(vol, out, {Compression::Zip}); }));
        fs::remove(out);
    }
    const auto dims = vol.grid->evalActiveVoxelDim();
    const double active = static_cast<double>(vol.grid->activeVoxelCount());
    std::printf("input: %s, %zu slices of %dx%d\n", gen ? "generated" : argv[1],
                stack.slices.size(), stack.slices.front().cols, stack.slices.front().rows);
    std::printf("grid: voxel %.3f mm, active box %dx%dx%d, %.1f M active voxels, %.1f MiB\n",
                vol.voxelSize() * 1e3, dims.x(), dims.y(), dims.z(), active * 1e-6,
                static_cast<double>(vol.grid->memUsage()) / (1 << 20));
    std::printf(
        "medians of %d: %s %.3f s, resample %.3f s (%.1f ns per active voxel), save blosc %.3f s, "
        "save mask %.3f s, save zip %.3f s (1 run)\n",
        repeats, gen ? "generate" : "read", median(tRead), median(tResample),
        median(tResample) / active * 1e9, median(tBlosc), median(tMask), median(tZip));
    std::printf(
        "CPU seconds (user + system, all threads), medians: %s %.3f, resample %.3f, "
        "save blosc %.3f, save mask %.3f\n",
        gen ? "generate" : "read", median(cRead), median(cResample), median(cBlosc), median(cMask));
    if (!gen) {
        std::printf("load (read + resample as palp convert runs them), medians: %.3f s, CPU %.3f\n",
                    median(tLoad), median(cLoad));
    }
    return 0;
}
