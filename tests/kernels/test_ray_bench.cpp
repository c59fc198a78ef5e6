#include <gtest/gtest.h>

#include "palp/bench/ray_bench.h"

namespace {

// Smoke pass of the benchmark harness: every figure is produced, positive, and the palp and
// OpenVDB-baseline first hits agree on (nearly) every ray. Timing itself is not asserted.
TEST(RayBench, SmokePass) {
    using namespace palp::kernels;
    RayBenchOptions o;
    o.frames = 20;
    o.warmUp = 2;
    o.batchBundles = 50;
    o.pin = false;
    o.warmBlockFrames = 5;
    RayBenchReport report;
    auto phantom = makeRayBenchPhantom(1e-3);
    o.rays = 25;
    benchVolumeRays(phantom, "phantom", o, report);
    o.rays = 17;
    benchMeshRays(o, nullptr, report);
    benchBatchRays(phantom, "phantom", o, report);
    // Volume: per set (trajectory, random) the line, the no-skip line and the warm-block line.
    ASSERT_EQ(report.lines.size(), 6u + 6u + 2u + 1u);
    for (const auto& l : report.lines) {
        EXPECT_GT(l.a.meanUs, 0) << l.name;
        EXPECT_GT(l.b.meanUs, 0) << l.name;
        EXPECT_FALSE(formatComparison(l).empty());
    }
    // "N/M rays agree": parse the first volume line's note.
    const std::string& note = report.lines[0].note;
    const auto slash = note.find('/');
    ASSERT_NE(slash, std::string::npos);
    const auto space = note.rfind(' ', slash);
    const long agree = std::stol(note.substr(space + 1, slash - space - 1));
    const long total = std::stol(note.substr(slash + 1));
    EXPECT_GT(total, 0);
    EXPECT_GE(static_cast<double>(agree), 0.98 * static_cast<double>(total)) << note;
}

}  // namespace
