// Partial rank correlations (palp/studies/prcc.h) against two independent computations on the
// same CSV: OpenTURNS' CorrelationAnalysis.computePRCC() and numpy/scipy (prcc_oracle.py), to
// 1e-9; and `palp errormap` writing its tables and figures and fitting the lookup table.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <random>

#include "palp/base/error.h"
#include "palp/studies/prcc.h"
#include "palp/studies/sweep_design.h"
#include "palp/studies/sweep_plots.h"
#include "test_support.h"

namespace {

namespace fs = std::filesystem;
using namespace palp::haptics;
using palp::test::TempDir;

TEST(Prcc, AverageRanksShareTies) {
    Eigen::VectorXd v(6);
    v << 3, 1, 3, 2, 3, 0;
    Eigen::VectorXd want(6);
    want << 5, 2, 5, 3, 5, 1;
    EXPECT_EQ(averageRanks(v), want);
}

/// A table of @p n rows: continuous, log-spaced, integer and two-valued variables (ties), a
/// response monotone in a mix of them plus noise, and a non-finite response in two rows.
void writeTable(const fs::path& csv, int n) {
    std::mt19937_64 rng(42);
    std::uniform_real_distribution<double> u(0, 1);
    std::normal_distribution<double> noise(0, 0.3);
    std::ofstream f(csv);
    f << "sample,strain,youngs,lod,primary,rate,density,err_rms\n";
    char buf[256];
    for (int i = 0; i < n; ++i) {
        const double strain = 0.01 + 0.07 * u(rng), youngs = 2000 * std::pow(10.0, u(rng));
        const double lod = u(rng) < 0.5 ? 2 : 4, primary = std::floor(5 + 115 * u(rng));
        const double rate = 25 + 475 * u(rng), density = 1000;
        double err = std::exp(0.8 * lod / 4 - 1.5 * primary / 120 + 10 * strain +
                              0.2 * std::log10(youngs) + noise(rng));
        if (i == 7) err = INFINITY;
        if (i == 11) err = NAN;
        std::snprintf(buf, sizeof buf, "%d,%.9g,%.9g,%.9g,%.9g,%.9g,%.9g,%.9g\n", i, strain, youngs,
                      lod, primary, rate, density, err);
        f << buf;
    }
}

TEST(Prcc, EqualsOpenTurnsAndScipy) {
    ASSERT_TRUE(fs::exists("/usr/bin/python3"));
    TempDir d;
    const fs::path csv = d / "table.csv";
    writeTable(csv, 600);
    const SweepTable t = readSweepTable(csv);  // no sidecar: every column a variable
    int dropped = 0, used = 0;
    const auto prcc = sweepPrcc(t, "err_rms", 0.95, &dropped, &used);
    EXPECT_EQ(dropped, 2);
    EXPECT_EQ(used, 598);
    // density is constant: left out; sample is an index column only with a sidecar, so it is
    // analysed here (a variable unrelated to the error).
    std::vector<std::string> names;
    std::string list;
    for (const auto& e : prcc) {
        names.push_back(e.name);
        list += (list.empty() ? "" : ",") + e.name;
    }
    ASSERT_EQ(names,
              (std::vector<std::string>{"sample", "strain", "youngs", "lod", "primary", "rate"}));
    const auto r = palp::test::runCommand("/usr/bin/python3 " PALP_PRCC_ORACLE " " + csv.string() +
                                          " err_rms " + list + " 0.95");
    ASSERT_EQ(r.exitCode, 0) << r.output;
    const auto j = nlohmann::json::parse(r.output);
    EXPECT_EQ(j["n"], 598);
    for (std::size_t k = 0; k < prcc.size(); ++k) {
        SCOPED_TRACE(prcc[k].name);
        EXPECT_NEAR(prcc[k].r, j["openturns"]["r"][k].get<double>(), 1e-9);
        EXPECT_NEAR(prcc[k].r, j["scipy"]["r"][k].get<double>(), 1e-9);
        EXPECT_NEAR(prcc[k].t, j["scipy"]["t"][k].get<double>(), 1e-9 * std::abs(prcc[k].t) + 1e-9);
        EXPECT_NEAR(prcc[k].p, j["scipy"]["p"][k].get<double>(), 1e-9);
        EXPECT_NEAR(prcc[k].lower, j["scipy"]["lower"][k].get<double>(), 1e-9);
        EXPECT_NEAR(prcc[k].upper, j["scipy"]["upper"][k].get<double>(), 1e-9);
        EXPECT_LT(prcc[k].lower, prcc[k].r);
        EXPECT_GT(prcc[k].upper, prcc[k].r);
    }
    // The structure put in comes out: strain, lod, E up; primary down; rate and index ~0.
    EXPECT_GT(prcc[1].r, 0.5);
    EXPECT_GT(prcc[2].r, 0.1);
    EXPECT_GT(prcc[3].r, 0.3);
    EXPECT_LT(prcc[4].r, -0.5);
    EXPECT_LT(std::abs(prcc[5].r), 0.12);
    EXPECT_LT(prcc[1].p, 1e-12);
    EXPECT_GT(prcc[5].p, 1e-3);
}

TEST(Prcc, RefusesWhatItCannotAnalyse) {
    Eigen::MatrixXd x = Eigen::MatrixXd::Random(5, 3);
    Eigen::VectorXd y = Eigen::VectorXd::Random(5);
    palp::test::expectThrowWith<palp::ValueError>(
        [&] {
            partialRankCorrelation(x, y, {"a", "b", "c"});
        },
        {"more than 6 rows", "found 5"});
    x = Eigen::MatrixXd::Random(20, 2);
    x.col(1).setConstant(2.0);
    palp::test::expectThrowWith<palp::ValueError>(
        [&] {
            partialRankCorrelation(x, Eigen::VectorXd::Random(20), {"a", "b"});
        },
        {"'b'", "constant"});
    TempDir d;
    palp::test::writeFile(d / "t.csv", "a,b\n1,2\n3,x\n");
    palp::test::expectThrowWith<palp::FormatError>([&] { readSweepTable(d / "t.csv"); },
                                                   {"t.csv", "line 3", "column 'b'", "'x'"});
}

TEST(Prcc, ErrormapWritesTablesAndFigures) {
    TempDir d;
    writeTable(d / "table.csv", 300);
    const auto r = palp::test::runCommand(palp::test::palpTool().string() + " errormap " +
                                          (d / "table.csv").string() + " -o " +
                                          (d / "map").string() + " 2>&1");
    ASSERT_EQ(r.exitCode, 0) << r.output;
    EXPECT_NE(r.output.find("primary"), std::string::npos) << r.output;
    for (const char* f : {"prcc.csv", "prcc.json", "parallel.png", "parallel.svg", "parallel.pdf",
                          "variables.png", "variables.svg", "variables.pdf"}) {
        SCOPED_TRACE(f);
        ASSERT_TRUE(fs::exists(d / "map" / f));
        EXPECT_GT(fs::file_size(d / "map" / f), 300u);
    }
    std::ifstream png(d / "map" / "parallel.png", std::ios::binary);
    char magic[8];
    png.read(magic, 8);
    EXPECT_EQ(std::string(magic + 1, 3), "PNG");
    std::ifstream svg(d / "map" / "variables.svg");
    const std::string text((std::istreambuf_iterator<char>(svg)), {});
    EXPECT_NE(text.find("<svg"), std::string::npos);
    // A subset: the rows with lod 2 (lod, now constant, drops out); a bad filter is refused.
    const auto sub = palp::test::runCommand(palp::test::palpTool().string() + " errormap " +
                                            (d / "table.csv").string() + " -o " +
                                            (d / "sub").string() + " --where lod=2 --no-plots");
    ASSERT_EQ(sub.exitCode, 0) << sub.output;
    EXPECT_NE(sub.output.find("primary"), std::string::npos);
    EXPECT_EQ(sub.output.find("\nlod"), std::string::npos) << sub.output;
    EXPECT_FALSE(fs::exists(d / "sub" / "parallel.png"));
    const auto where = palp::test::runCommand(palp::test::palpTool().string() + " errormap " +
                                              (d / "table.csv").string() + " -o " +
                                              (d / "sub").string() + " --where lod 2>&1");
    EXPECT_EQ(where.exitCode, 1);
    EXPECT_NE(where.output.find("--where: expected COLUMN=NUMBER"), std::string::npos)
        << where.output;
    // A response that is not a column is refused by name.
    const auto bad = palp::test::runCommand(palp::test::palpTool().string() + " errormap " +
                                            (d / "table.csv").string() + " -o " +
                                            (d / "m2").string() + " --response err 2>&1");
    EXPECT_EQ(bad.exitCode, 1);
    EXPECT_NE(bad.output.find("--response"), std::string::npos) << bad.output;
}

// `palp errormap --table`: the lookup table fitted to the rows, its provenance and coverage;
// without -o only the table; with neither, a refusal.
TEST(Prcc, ErrormapFitsTheLookupTable) {
    TempDir d;
    writeTable(d / "table.csv", 600);
    const std::string table = (d / "t.json").string();
    const auto r = palp::test::runCommand(palp::test::palpTool().string() + " errormap " +
                                          (d / "table.csv").string() + " --table " + table +
                                          " --table-response err_rms 2>&1");
    ASSERT_EQ(r.exitCode, 0) << r.output;
    EXPECT_NE(r.output.find("598 rows (2 non-finite left out)"), std::string::npos) << r.output;
    std::ifstream in(table);
    const nlohmann::json j = nlohmann::json::parse(in);
    EXPECT_EQ(j["palp_error_table"], 1);
    EXPECT_EQ(j["response"], "err_rms");
    EXPECT_DOUBLE_EQ(j["quantile"].get<double>(), 0.95);
    EXPECT_EQ(j["axes"][0]["name"], "lod");
    EXPECT_EQ(j["axes"][0]["values"], nlohmann::json({2, 4}));
    EXPECT_EQ(j["axes"][1]["name"], "primary");
    EXPECT_EQ(j["provenance"]["fit"]["rows_used"], 598);
    EXPECT_EQ(j["provenance"]["fit"]["rows_non_finite"], 2);
    // The 95th percentile of the residuals per lod: about 95 % of the rows at or below.
    EXPECT_NEAR(j["provenance"]["fit"]["coverage"].get<double>(), 0.95, 0.01);
    std::size_t nodes = 1;
    for (const auto& a : j["axes"]) nodes *= a["values"].size();
    EXPECT_EQ(j["error_percent"].size(), nodes);
    EXPECT_FALSE(fs::exists(d / "map"));
    const auto none = palp::test::runCommand(palp::test::palpTool().string() + " errormap " +
                                             (d / "table.csv").string() + " 2>&1");
    EXPECT_EQ(none.exitCode, 1);
    EXPECT_NE(none.output.find("-o DIR, --table FILE"), std::string::npos) << none.output;
}

TEST(Prcc, SweepCommandRefusesBadRangesBeforeWritingAnything) {
    TempDir d;
    palp::test::writeFile(d / "r.json", R"({"palp_sweep_ranges": 1, "mesh": {"nodes": 7,
        "spacing_mm": 5}, "duration_s": 0.02, "adaptivity_per_reference": 3, "variables": {
        "strain": {"min": 0.06, "max": 0.01}}})");
    const auto r = palp::test::runCommand(palp::test::palpTool().string() + " sweep " +
                                          (d / "r.json").string() + " -n 4 -o " +
                                          (d / "out").string() + " 2>&1");
    EXPECT_EQ(r.exitCode, 1);
    EXPECT_NE(r.output.find("r.json: field 'variables.strain': expected min < max, found an "
                            "inverted range"),
              std::string::npos)
        << r.output;
    EXPECT_FALSE(fs::exists(d / "out"));
    const auto merge = palp::test::runCommand(palp::test::palpTool().string() + " sweep merge " +
                                              (d / "nothing").string() + " -o " +
                                              (d / "t.csv").string() + " 2>&1");
    EXPECT_EQ(merge.exitCode, 1);
    EXPECT_NE(merge.output.find("manifest.json: no sweep manifest"), std::string::npos)
        << merge.output;
}

}  // namespace
