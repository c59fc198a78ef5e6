// The sweep's ranges file and sampler (palp/studies/sweep_design.h): Philox known answers, Latin
// hypercube strata, streams that depend only on (seed, index), and refusals of bad ranges.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <set>

#include "palp/base/error.h"
#include "palp/studies/sweep_design.h"
#include "palp/studies/sweep_store.h"
#include "sweep_fixture.h"
#include "test_support.h"

namespace {

using namespace palp::haptics;
using palp::test::expectThrowWith;
using palp::test::smallRanges;

SweepSpec spec(std::int64_t n, std::uint64_t seed = 11, SweepDesign d = SweepDesign::lhs) {
    SweepSpec s;
    s.ranges = parseSweepRanges(smallRanges(), "small.json");
    s.samples = n;
    s.seed = seed;
    s.design = d;
    return s;
}

TEST(SweepDesign, PhiloxMatchesRandom123KnownAnswers) {
    // Random123's kat_vectors, philox4x32 with 10 rounds.
    using A = std::array<std::uint32_t, 4>;
    EXPECT_EQ(philox({0, 0}, {0, 0, 0, 0}), (A{0x6627e8d5, 0xe169c58d, 0xbc57ac4c, 0x9b00dbd8}));
    EXPECT_EQ(philox({0xffffffff, 0xffffffff}, {0xffffffff, 0xffffffff, 0xffffffff, 0xffffffff}),
              (A{0x408f276d, 0x41c83b0e, 0xa20bc7c6, 0x6d5451fd}));
    EXPECT_EQ(philox({0xa4093822, 0x299f31d0}, {0x243f6a88, 0x85a308d3, 0x13198a2e, 0x03707344}),
              (A{0xd16cfe09, 0x94fdcceb, 0x5001e420, 0x24126ea1}));
    EXPECT_GT(unitOpen(0), 0.0);
    EXPECT_LT(unitOpen(~std::uint64_t{0}), 1.0);
}

TEST(SweepDesign, LatinHypercubeHitsEveryStratumOnce) {
    const SweepSpec s = spec(60);  // 20 groups of 3
    const SweepSampler sampler(s);
    for (int v : {0, 1, 4, 6, 9}) {  // uniform variables
        const SweepRange& r = s.ranges.vars[static_cast<std::size_t>(v)];
        const bool group = sweepVarInfo(v).perGroup;
        const std::int64_t strata = group ? s.groups() : s.samples;
        std::set<std::int64_t> hit;
        for (std::int64_t i = 0; i < s.samples; i += group ? s.groupSize() : 1) {
            const double x = sampler.sample(i)[static_cast<std::size_t>(v)];
            ASSERT_GE(x, r.min);
            ASSERT_LT(x, r.max);
            hit.insert(static_cast<std::int64_t>(
                std::floor((x - r.min) / (r.max - r.min) * static_cast<double>(strata))));
        }
        EXPECT_EQ(static_cast<std::int64_t>(hit.size()), strata) << sweepVarInfo(v).name;
    }
    // A group shares its input and material; its adaptivity varies.
    const auto a = sampler.sample(3), b = sampler.sample(4);
    for (int v = 0; v < kSweepVarCount; ++v) {
        const auto k = static_cast<std::size_t>(v);
        if (sweepVarInfo(v).perGroup) {
            EXPECT_EQ(a[k], b[k]) << sweepVarInfo(v).name;
        }
    }
    EXPECT_NE(a[9], b[9]);  // rate
    // Log scale: strata equal in log E.
    std::set<int> logHit;
    for (std::int64_t g = 0; g < s.groups(); ++g) {
        const double e = sampler.sample(g * 3)[3];
        logHit.insert(static_cast<int>(std::floor(std::log(e / 2000.0) / std::log(10.0) * 20)));
    }
    EXPECT_EQ(logHit.size(), 20u);
    // Discrete values come out in proportion (values [1, 2]: 30 each over 60 strata).
    int lod2 = 0;
    for (std::int64_t i = 0; i < 60; ++i) lod2 += sampler.sample(i)[7] == 2.0;
    EXPECT_EQ(lod2, 30);
}

TEST(SweepDesign, StreamsDependOnSeedAndIndexOnly) {
    for (SweepDesign d : {SweepDesign::lhs, SweepDesign::mc}) {
        const SweepSpec s = spec(37, 5, d);
        const SweepSampler one(s), other(s);
        std::vector<std::array<double, kSweepVarCount>> forward;
        for (std::int64_t i = 0; i < s.samples; ++i) forward.push_back(one.sample(i));
        // Another process, another order, any shard split: the same values.
        for (std::int64_t i = s.samples - 1; i >= 0; --i)
            EXPECT_EQ(other.sample(i), forward[static_cast<std::size_t>(i)]);
        for (std::int64_t n = 1; n <= 7; ++n) {
            std::int64_t at = 0;
            for (std::int64_t i = 0; i < n; ++i) {
                const SampleRange r = shardRange(s, i, n);
                if (r.size() == 0) continue;
                EXPECT_EQ(r.first, at) << n;
                EXPECT_EQ(r.first % s.groupSize(), 0);
                at = r.end;
            }
            EXPECT_EQ(at, s.samples) << n;
        }
        // Another seed: other values.
        const SweepSampler seeded(spec(37, 6, d));
        EXPECT_NE(seeded.sample(0), forward[0]);
        // Fixed variables stay fixed.
        EXPECT_EQ(forward[5][5], 1000.0);
    }
    // LHS and MC differ, and so do their ids.
    EXPECT_NE(spec(37, 5, SweepDesign::lhs).id(), spec(37, 5, SweepDesign::mc).id());
    EXPECT_NE(spec(37, 5).id(), spec(38, 5).id());
    EXPECT_EQ(spec(37, 5).id(), spec(37, 5).id());
}

TEST(SweepDesign, RefusesBadRangesNamingTheField) {
    using palp::FormatError;
    using palp::ValueError;
    auto with = [](const std::string& var, const std::string& specText) {
        std::string t = smallRanges();
        const auto at = t.find("\"" + var + "\":");
        const auto end = t.find('}', at);
        return t.substr(0, at) + "\"" + var + "\": " + specText + t.substr(end + 1);
    };
    expectThrowWith<ValueError>(
        [] { parseSweepRanges(smallRanges(", \"stiffness\": {\"value\": 1}"), "r.json"); },
        {"r.json", "variables.stiffness", "unknown variable", "strain"});
    expectThrowWith<ValueError>(
        [&] { parseSweepRanges(with("poisson", R"({"min": 0.3, "max": 0.3})"), "r.json"); },
        {"r.json", "variables.poisson", "non-empty range", "min = max = 0.3"});
    expectThrowWith<ValueError>(
        [&] { parseSweepRanges(with("youngs", R"({"min": 9000, "max": 2000})"), "r.json"); },
        {"r.json", "variables.youngs", "inverted", "9000"});
    expectThrowWith<FormatError>(
        [&] { parseSweepRanges(with("damping", R"({"min": "NaN", "max": 3})"), "r.json"); },
        {"r.json", "variables.damping.min", "expected a number", "string"});
    expectThrowWith<FormatError>(
        [&] { parseSweepRanges(with("damping", R"({"min": NaN, "max": 3})"), "r.json"); },
        {"r.json", "not a JSON ranges file"});
    expectThrowWith<FormatError>(
        [&] { parseSweepRanges(with("damping", R"({"min": 1, "max": 1e999})"), "r.json"); },
        {"r.json", "number overflow", "1e999"});
    expectThrowWith<ValueError>(
        [&] { parseSweepRanges(with("lod", R"({"values": [1, 3]})"), "r.json"); },
        {"r.json", "variables.lod", "1, 2 or 4", "3"});
    expectThrowWith<ValueError>(
        [&] {
            parseSweepRanges(with("contact", R"({"min": 0, "max": 25, "integer": true})"),
                             "r.json");
        },
        {"r.json", "variables.contact", "below 25", "25"});
    expectThrowWith<ValueError>(
        [&] { parseSweepRanges(with("primary", R"({"min": 3, "max": 12})"), "r.json"); },
        {"r.json", "variables.primary", "integers"});
    expectThrowWith<ValueError>(
        [&] { parseSweepRanges(with("poisson", R"({"min": 0.3, "max": 0.5})"), "r.json"); },
        {"r.json", "variables.poisson", "[0, 0.49] 1", "found 0.5"});
    expectThrowWith<ValueError>(
        [&] {
            parseSweepRanges(with("rate", R"({"min": 0, "max": 10, "scale": "log"})"), "r.json");
        },
        {"r.json", "variables.rate.min", "> 0 on a log scale"});
    std::string missing = smallRanges();
    const std::string density = "\"density\": {\"value\": 1000}, ";
    missing.erase(missing.find(density), density.size());
    expectThrowWith<ValueError>([&] { parseSweepRanges(missing, "r.json"); },
                                {"r.json", "variables.density", "missing"});
    expectThrowWith<FormatError>([] { parseSweepRanges("[1, 2]", "r.json"); },
                                 {"r.json", "expected a JSON object", "array"});
    expectThrowWith<palp::IoError>([] { loadSweepRanges("/nonexistent/r.json"); },
                                   {"/nonexistent/r.json", "cannot read"});
    expectThrowWith<ValueError>([] { SweepSampler s(spec(0)); }, {"samples", "found 0"});
    expectThrowWith<ValueError>([] { parseShard("3/3"); }, {"--shard", "3/3"});
    expectThrowWith<ValueError>([] { parseShard("1/x"); }, {"--shard", "1/x"});
    EXPECT_EQ(parseShard("2/5"), (std::pair<std::int64_t, std::int64_t>{2, 5}));
}

}  // namespace
