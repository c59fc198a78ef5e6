// `palp palpate --deformable --material linear|neo-hookean` and `--material-table`: presses on
// the bone phantom at increasing depth feel neo-Hookean tissue stiffen (its force over the
// linear force rises with depth), the report says which law ran, on which solver and why, and
// bad values and tables are refused naming the option, the file and the row.

#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <fstream>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "test_support.h"

namespace {

using palp::test::runCommand;

/// The JSON report of `palp palpate ARGS --json` (exit 0 expected); empty on failure.
nlohmann::json palpate(const std::string& args) {
    const auto r = runCommand(palp::test::palpTool().string() + " palpate " + args + " --json");
    EXPECT_EQ(r.exitCode, 0) << args << "\n" << r.output;
    const auto brace = r.output.find('{');
    if (brace == std::string::npos) return nlohmann::json::object();
    const auto j = nlohmann::json::parse(r.output.substr(brace), nullptr, false);
    EXPECT_FALSE(j.is_discarded()) << r.output;
    return j.is_discarded() ? nlohmann::json::object() : j;
}

/// The force the bone phantom's tissue holds @p depthMm deep (VC, 5 mm cells, a 6 mm filter):
/// the mean over the last 0.2 s of a 0.6 s hold, from the trace (N); the report in @p report.
double holdForce(const std::string& material, double depthMm, nlohmann::json& report) {
    palp::test::TempDir tmp;
    const std::string trace = (tmp / "t.csv").string();
    char depth[32];
    std::snprintf(depth, sizeof depth, "%g", depthMm);
    report = palpate("--phantom bone --deformable --material " + material +
                     " --filter-mm 6 --fast --trajectory press --hold 0.6 --mode vc --k-base 600 "
                     "--depth " +
                     std::string(depth) + " --trace " + trace);
    // The press starts 15 mm out (0.15 s of its 100 mm/s) and reaches the depth after
    // (depth + 15 mm) / 100 mm/s; the hold's last 0.2 s are steady.
    const double pressed = (depthMm + 15) / 100;
    std::ifstream in(trace);
    std::string line;
    std::getline(in, line);  // header: t,tick,...,force_x,force_y,force_z,... (columns 8-10)
    double sum = 0;
    int n = 0;
    while (std::getline(in, line)) {
        std::vector<double> v;
        std::size_t pos = 0;
        for (int c = 0; c < 11; ++c) {
            const std::size_t comma = line.find(',', pos);
            v.push_back(std::stod(line.substr(pos, comma - pos)));
            pos = comma + 1;
        }
        if (v[0] < pressed + 0.35 || v[0] > pressed + 0.55) continue;
        sum += std::sqrt(v[8] * v[8] + v[9] * v[9] + v[10] * v[10]);
        ++n;
    }
    EXPECT_GT(n, 150) << material << " at " << depthMm << " mm";
    return n > 0 ? sum / n : 0;
}

// A press held still is a quasi-static indentation: the force is the tissue's reaction at the
// dent. Neo-Hookean tissue has the linear tissue's small-strain E and nu and stiffens as it is
// compressed, so the ratio of its force to the linear force rises with the depth (measured:
// 1.008, 1.020, 1.034 at 3, 6, 10 mm).
TEST(PalpateMaterial, NeoHookeanTissueStiffensWithDepthOnTheBonePhantom) {
    double previousRatio = 0;
    for (const double depth : {3.0, 6.0, 10.0}) {
        nlohmann::json linear, neo;
        const double fl = holdForce("linear", depth, linear);
        const double fn = holdForce("neo-hookean", depth, neo);
        ASSERT_TRUE(linear.contains("deformable") && neo.contains("deformable"));
        EXPECT_EQ(linear["deformable"]["material"], "linear");
        EXPECT_EQ(neo["deformable"]["material"], "neo-hookean");
        EXPECT_EQ(neo["deformable"]["solver"], "explicit");
        EXPECT_EQ(neo["faulted_ticks"], 0);
        const double ratio = fn / fl;
        std::printf("depth %4.1f mm: held force linear %.4f N, neo-Hookean %.4f N, ratio %.4f\n",
                    depth, fl, fn, ratio);
        EXPECT_GT(fl, 0.05 * depth);  // the press reaches the tissue
        EXPECT_GT(ratio, previousRatio + 0.005) << "at " << depth << " mm";
        previousRatio = ratio;
    }
    EXPECT_GT(previousRatio, 1.02);  // the neo-Hookean force grows faster than the linear one
}

// --fem-solver auto puts neo-Hookean tissue on the whole mesh within the budget and says why, in
// text and JSON; the JSON names the law and the table; --fem-solver regions runs it with a TLED
// primary.
TEST(PalpateMaterial, AutoSaysWhyNeoHookeanRunsOnTheWholeMesh) {
    const auto j = palpate(
        "--phantom bone --deformable --material neo-hookean --fast --trajectory press --seconds "
        "0.05");
    ASSERT_TRUE(j.contains("deformable"));
    EXPECT_EQ(j["deformable"]["solver"], "explicit");
    EXPECT_EQ(j["deformable"]["solver_asked"], "auto");
    EXPECT_NE(j["deformable"]["solver_reason"].get<std::string>().find("(neo-Hookean: TLED)"),
              std::string::npos)
        << j["deformable"];
    EXPECT_EQ(j["deformable"]["material_table"], "none");
    const auto text = runCommand(palp::test::palpTool().string() +
                                 " palpate --phantom bone --deformable --material neo-hookean "
                                 "--fast --trajectory press --seconds 0.05");
    EXPECT_EQ(text.exitCode, 0) << text.output;
    EXPECT_NE(text.output.find("neo-Hookean, E 5 kPa, whole mesh: "), std::string::npos)
        << text.output;
    EXPECT_NE(text.output.find("(neo-Hookean: TLED)"), std::string::npos) << text.output;
    const auto regions = palpate(
        "--phantom bone --deformable --material neo-hookean --fem-solver regions --fast "
        "--trajectory press --seconds 0.2");
    ASSERT_TRUE(regions.contains("deformable"));
    EXPECT_EQ(regions["deformable"]["solver"], "regions");
    EXPECT_EQ(regions["deformable"]["material"], "neo-hookean");
    EXPECT_GT(regions["max_force_n"].get<double>(), 0.0) << regions;
}

// The CT table on the tumour phantom (fat, soft tissue at 40 HU, the inclusion at 200 HU): the
// report lists the table's rows and the lesion's modulus.
TEST(PalpateMaterial, TheShippedCtTableRunsAndIsReported) {
    const auto j = palpate(
        "--phantom tumour --deformable --material-table ct --fast --trajectory press --seconds "
        "0.05");
    ASSERT_TRUE(j.contains("deformable"));
    const auto& t = j["deformable"]["material_table"];
    ASSERT_TRUE(t.is_object()) << j["deformable"];
    EXPECT_EQ(t["kind"], "ranges");
    EXPECT_EQ(t["poisson"], 0.45);
    ASSERT_EQ(t["rows"].size(), 3u);
    EXPECT_EQ(t["rows"][2]["name"], "lesion");
    EXPECT_DOUBLE_EQ(t["rows"][2]["youngs_kpa"].get<double>(), 19.99);
    EXPECT_TRUE(j["deformable"]["young_kpa"].is_null());  // the table's moduli, not --young-kpa
}

TEST(PalpateMaterial, BadValuesAndTablesAreRefusedNamingTheOptionFileAndRow) {
    palp::test::TempDir tmp;
    const std::string bad = (tmp / "overlap.csv").string();
    {
        std::ofstream(bad) << "name,lo,hi,youngs_pa,poisson,density_kg_m3,source\n"
                              "fat,-200,-30,3000,0.45,1000,ref\n"
                              "soft,-50,150,4000,0.45,1000,ref\n";
    }
    const std::string base = palp::test::palpTool().string() +
                             " palpate --phantom bone --deformable --fast --seconds 0.05 ";
    struct Case {
        std::string args, message;
    };
    const Case cases[] = {
        {"--material rubber", "--material"},
        {"--material-table " + bad,
         "--material-table " + bad + ": " + bad +
             " line 3 (row 'soft') lo: expected a range that overlaps no other row's"},
        {"--material-table ct --young-kpa 8",
         "--young-kpa: expected no --young-kpa with --material-table"},
        {"--material-table " + (tmp / "missing.csv").string(), "--material-table"},
    };
    for (const Case& c : cases) {
        const auto r = runCommand(base + c.args);
        EXPECT_EQ(r.exitCode, 1) << c.args << "\n" << r.output;
        EXPECT_NE(r.output.find(c.message), std::string::npos) << c.args << "\n" << r.output;
    }
    // Without --deformable the FEM options are refused as before.
    const auto rigid = runCommand(palp::test::palpTool().string() +
                                  " palpate --phantom bone --fast --seconds 0.05 --material "
                                  "neo-hookean");
    EXPECT_EQ(rigid.exitCode, 1) << rigid.output;
    EXPECT_NE(rigid.output.find("--material: expected --deformable"), std::string::npos)
        << rigid.output;
}

}  // namespace
