// The regions' error lookup table and its control (error_table.h, error_control.h): the
// multilinear interpolation (exact at the nodes, linear between, clamped and flagged outside),
// refusal of bad tables naming the file and the field, the file round trip and the built-in
// table, the primary's cost against the regions' own cell count, the set-up choice and the
// run-time estimate of the input.
#include <gtest/gtest.h>

#include <cmath>
#include <numbers>
#include <string>

#include "alloc_counter.h"
#include "palp/base/error.h"
#include "palp/fem/async_regions.h"
#include "palp/haptics/tissue/error_control.h"
#include "palp/haptics/tissue/error_table.h"

namespace palp::haptics {
namespace {

std::size_t at(ErrorVar v) { return errorIndex(v); }

// A multilinear function of lod, primary and poisson: the interpolation reproduces it exactly.
double affine(double lod, double primary, double poisson) {
    return 1 + 2 * lod - 0.05 * primary + 3 * poisson + 0.01 * lod * primary;
}

ErrorTable affineTable() {
    std::vector<ErrorTable::Axis> axes = {{ErrorVar::lod, {2, 4}},
                                          {ErrorVar::primary, {5, 20, 60}},
                                          {ErrorVar::poisson, {0.3, 0.39, 0.48}}};
    std::vector<double> v;
    for (double l : axes[0].values)
        for (double p : axes[1].values)
            for (double n : axes[2].values) v.push_back(affine(l, p, n));
    return ErrorTable(axes, v, "affine");
}

ErrorPoint point(double lod, double primary, double poisson) {
    ErrorPoint x{};
    x.fill(std::numeric_limits<double>::quiet_NaN());  // not axes: ignored
    x[at(ErrorVar::lod)] = lod;
    x[at(ErrorVar::primary)] = primary;
    x[at(ErrorVar::poisson)] = poisson;
    return x;
}

TEST(ErrorTable, ExactAtNodesAndLinearBetween) {
    const ErrorTable t = affineTable();
    for (double l : {2.0, 4.0})
        for (double p : {5.0, 20.0, 60.0})
            for (double n : {0.3, 0.39, 0.48}) {
                const ErrorEstimate e = t.estimate(point(l, p, n));
                EXPECT_DOUBLE_EQ(e.percent, affine(l, p, n));
                EXPECT_TRUE(e.inRange());
            }
    // Between the nodes: the multilinear function itself (the table holds one exactly).
    for (auto [l, p, n] : {std::array<double, 3>{2.5, 7, 0.31}, {3.9, 44, 0.47}, {3, 20, 0.4}})
        EXPECT_NEAR(t.estimate(point(l, p, n)).percent, affine(l, p, n), 1e-12);
    // Along one axis between two nodes: the straight line between their values.
    const double a = t.estimate(point(2, 20, 0.39)).percent,
                 b = t.estimate(point(2, 60, 0.39)).percent;
    EXPECT_NEAR(t.estimate(point(2, 30, 0.39)).percent, a + 0.25 * (b - a), 1e-12);
}

TEST(ErrorTable, ClampsAndFlagsOutsideTheAxes) {
    const ErrorTable t = affineTable();
    const ErrorEstimate e = t.estimate(point(2, 100, 0.2));
    EXPECT_EQ(e.clampedAxes, (1u << 1) | (1u << 2));  // primary and poisson
    EXPECT_FALSE(e.inRange());
    EXPECT_DOUBLE_EQ(e.percent, affine(2, 60, 0.3));
    EXPECT_TRUE(std::isnan(t.estimate(point(2, NAN, 0.4)).percent));
    // Real-time: no allocation.
    const auto before = test::threadAllocationCount();
    double s = 0;
    for (int i = 0; i < 100; ++i) s += t.estimate(point(2 + i * 0.02, 5 + i, 0.3)).percent;
    EXPECT_EQ(test::threadAllocationCount(), before);
    EXPECT_GT(s, 0);
}

std::string tableJson(const std::string& axes, const std::string& values,
                      const std::string& extra = "") {
    return "{\"palp_error_table\": 1, \"response\": \"err_peak\", \"quantile\": 0.9, "
           "\"coupling\": 1, \"axes\": " +
           axes + ", \"error_percent\": " + values + extra + "}";
}

void expectRefused(const std::string& text, const std::string& field, const std::string& what) {
    try {
        ErrorTable::parse(text, "t.json");
        ADD_FAILURE() << "accepted: " << text;
    } catch (const Error& e) {
        const std::string m = e.what();
        EXPECT_NE(m.find("t.json"), std::string::npos) << m;
        EXPECT_NE(m.find(field), std::string::npos) << m;
        EXPECT_NE(m.find(what), std::string::npos) << m;
    }
}

TEST(ErrorTable, RefusesBadTablesNamingFileAndField) {
    const std::string axes = R"([{"name": "lod", "values": [2, 4]},
                                 {"name": "primary", "values": [5, 20, 60]}])";
    EXPECT_NO_THROW(ErrorTable::parse(tableJson(axes, "[1, 2, 3, 4, 5, 6]"), "t.json"));
    expectRefused("{\"palp_error_table\": 1, \"axes\": " + axes + "}", "error_percent", "a field");
    expectRefused(tableJson(axes, "[1, 2, 3, 4, 5]"), "error_percent", "6 values");
    expectRefused(tableJson(R"([{"name": "primary", "values": [5, 60, 20]}])", "[1, 2, 3]"),
                  "axes[0].values[2]", "increasing");
    expectRefused(tableJson(R"([{"name": "primary", "values": [5]}])", "[1]"), "axes[0].values",
                  "at least 2");
    expectRefused(tableJson(R"([{"name": "stiffness", "values": [1, 2]}])", "[1, 2]"),
                  "axes[0].name", "one of");
    expectRefused(tableJson(R"([{"name": "lod", "values": [2, 4]}, {"name": "lod", "values": [1,
                  2]}])",
                            "[1, 2, 3, 4]"),
                  "axes[1].name", "once");
    // JSON has no NaN: a string "NaN" is not a number, 1e999 overflows to infinity.
    expectRefused(tableJson(axes, R"([1, 2, "NaN", 4, 5, 6])"), "error_percent[2]", "a number");
    expectRefused(tableJson(axes, "[1, 2, 3, 1e999, 5, 6]"), "(file)", "1e999");
    expectRefused(tableJson(axes, "[1, 2, 3, -4, 5, 6]"), "error_percent[3]", ">= 0");
    expectRefused(tableJson(axes, "[1, 2, 3, 4, 5, 6]", ", \"quantile\": 1.5"), "quantile", "");
    expectRefused("{\"palp_error_table\": 2}", "palp_error_table", "version 1");
    expectRefused("[1, 2", "(file)", "JSON");
    EXPECT_THROW(ErrorTable::load("/nonexistent/t.json"), IoError);
}

TEST(ErrorTable, RoundTripAndBuiltIn) {
    const ErrorTable t = affineTable();
    const ErrorTable u = ErrorTable::parse(t.toJson(), "round trip");
    ASSERT_EQ(u.axes().size(), 3u);
    for (double p : {5.0, 13.0, 60.0})
        EXPECT_NEAR(u.estimate(point(3, p, 0.35)).percent, t.estimate(point(3, p, 0.35)).percent,
                    1e-7);
    const ErrorTable& b = ErrorTable::builtIn();
    ASSERT_NE(b.axis(ErrorVar::lod), nullptr);
    ASSERT_NE(b.axis(ErrorVar::primary), nullptr);
    EXPECT_EQ(b.coupling, 1);
    EXPECT_NE(b.provenance.find("sweep"), std::string::npos);
    ErrorPoint x{};
    for (const auto& a : b.axes()) x[at(a.var)] = 0.5 * (a.values.front() + a.values.back());
    const ErrorEstimate e = b.estimate(x);
    EXPECT_TRUE(e.inRange());
    EXPECT_GT(e.percent, 0);
    EXPECT_LT(e.percent, 100);
}

// The cost model counts the cells the regions integrate: the same number as AsyncRegions.
TEST(ErrorControl, PrimaryCostCountsTheRegionsCells) {
    const fem::FemModel model(fem::HexMesh::box(Eigen::Vector3d::Constant(0.04), {9, 9, 9}),
                              fem::ElasticMaterial{5000, 0.45, 1000, 10, 0});
    fem::Constraints k(model.dofCount());
    k.fixNodes(model.mesh().faceNodes(fem::BoxFace::zMin));
    const int centre = model.mesh().node(4, 4, 8), corner = model.mesh().node(1, 2, 8);
    for (auto [lod, seeds, contact] :
         {std::array<int, 3>{2, 5, centre}, {2, 30, centre}, {4, 10, corner}, {1, 20, corner}}) {
        fem::AsyncRegionsOptions o;
        o.lod = lod;
        o.primaryNodes = seeds;
        o.globalSecondary = false;
        const fem::AsyncRegions r(model, k, {contact}, o);
        const PrimaryCost c = primaryCost(model, contact, lod, seeds, 0.9, 1e-3);
        EXPECT_EQ(c.cells, r.primaryCellCount()) << "lod " << lod << ", " << seeds << " seeds";
        EXPECT_DOUBLE_EQ(c.substeps, fem::explicitSubstepsPerTick(model, 0.9, 1e-3));
        EXPECT_GE(c.substeps, 1);
    }
    EXPECT_THROW(primaryCost(model, centre, 3, 5, 0.9, 1e-3), ValueError);
    EXPECT_THROW(primaryCost(model, -1, 2, 5, 0.9, 1e-3), ValueError);
}

// A table falling with the primary size: the controller takes the smallest primary within
// the budget; with the tick too tight for it, the best that fits, flagged.
TEST(ErrorControl, ChoosesTheCheapestSettingWithinTheBudget) {
    std::vector<ErrorTable::Axis> axes = {{ErrorVar::primary, {5, 20, 60}},
                                          {ErrorVar::rate, {25, 500}}};
    // 12 % at 5 seeds, 6 % at 20, 2 % at 60; 1 point less at 500 Hz.
    const ErrorTable t(axes, {12, 11, 6, 5, 2, 1});
    const auto cost = [](int n) { return PrimaryCost{10 * n, 2}; };
    ErrorControlOptions o;
    o.primaryCandidates = {5, 10, 20, 40, 60};
    o.rateCandidates = {25, 500};
    ErrorPoint x{};
    ErrorControlChoice c = chooseRegionsSetting(t, x, 2, cost, o);  // budget 5.23 %
    // 5.23 % needs 6 - (6 - 2) (n - 20) / 40 <= 5.23 at 25 Hz (n >= 27.7) or 5 - ... at 500 Hz
    // (n >= 20 is 5 %): 20 seeds at 500 Hz.
    EXPECT_EQ(c.setting.primaryNodes, 20);
    EXPECT_EQ(c.setting.secondaryRate, 500);
    EXPECT_NEAR(c.predicted.percent, 5, 1e-12);
    EXPECT_TRUE(c.meetsBudget && c.meetsTime);
    EXPECT_EQ(c.candidates, 10);
    EXPECT_NE(c.reason.find("5.00 %"), std::string::npos) << c.reason;
    o.budgetPercent = 2.5;  // needs 60 seeds: 1,200 element-substeps
    c = chooseRegionsSetting(t, x, 2, cost, o);
    EXPECT_EQ(c.setting.primaryNodes, 60);
    o.maxElementSubsteps = 900;  // 40 seeds fit: the smallest error there, flagged
    c = chooseRegionsSetting(t, x, 2, cost, o);
    EXPECT_EQ(c.setting.primaryNodes, 40);
    EXPECT_EQ(c.setting.secondaryRate, 500);
    EXPECT_FALSE(c.meetsBudget);
    EXPECT_TRUE(c.meetsTime);
    o.maxElementSubsteps = 10;  // nothing fits: the cheapest
    c = chooseRegionsSetting(t, x, 2, cost, o);
    EXPECT_EQ(c.setting.primaryNodes, 5);
    EXPECT_FALSE(c.meetsTime);
    o.budgetPercent = -1;
    EXPECT_THROW(chooseRegionsSetting(t, x, 2, cost, o), ValueError);
    // Out of reach, with a rate that barely matters: not the faster secondary for 1 % less.
    const ErrorTable flat(axes, {12, 11.9, 6, 5.95, 2, 1.98});
    o.budgetPercent = 1;
    o.maxElementSubsteps = 8000;
    c = chooseRegionsSetting(flat, x, 2, cost, o);
    EXPECT_EQ(c.setting.primaryNodes, 60);
    EXPECT_EQ(c.setting.secondaryRate, 25);
    EXPECT_FALSE(c.meetsBudget);
}

// The monitor reads a raised-cosine press's amplitude and frequency from its displacement.
TEST(ErrorControl, MonitorEstimatesTheInput) {
    std::vector<ErrorTable::Axis> axes = {{ErrorVar::strain, {0.01, 0.08}},
                                          {ErrorVar::frequency, {2, 6}}};
    const ErrorTable t(axes, {1, 3, 2, 8});  // strain 0.01: 1 at 2 Hz, 3 at 6 Hz; 0.08: 2, 8
    ErrorPoint x{};
    ErrorMonitor m(t, x, 0.06, 0.25, 1e-3, 3.0);
    const double a = 0.003, f = 4;  // 3 mm on 60 mm: strain 0.05; one period a window
    const auto before = test::threadAllocationCount();
    for (int k = 1; k <= 1000; ++k)
        m.update(a * 0.5 * (1 - std::cos(2 * std::numbers::pi * f * k * 1e-3)));
    EXPECT_EQ(test::threadAllocationCount(), before);
    EXPECT_EQ(m.windows(), 4);
    EXPECT_NEAR(m.strain(), 0.05, 1e-9);
    EXPECT_NEAR(m.frequency(), 4, 0.02);
    ErrorPoint p{};
    p[at(ErrorVar::strain)] = 0.05;
    p[at(ErrorVar::frequency)] = 4;
    EXPECT_NEAR(m.current().percent, t.estimate(p).percent, 0.02);
    EXPECT_TRUE(m.current().inRange());
    EXPECT_EQ(m.windowsOverBudget(), 4);  // 3.71 % against a budget of 3 %
    EXPECT_NEAR(m.maxPercent(), 3.714, 0.01);
    // A held press: no travel, frequency 0, clamped to the table's 2 Hz and flagged.
    for (int k = 0; k < 250; ++k) m.update(0.0012);
    EXPECT_NEAR(m.strain(), 0.02, 1e-12);
    EXPECT_EQ(m.frequency(), 0);
    EXPECT_EQ(m.current().clampedAxes, 1u << 1);
    // No contact: no window counted.
    for (int k = 0; k < 250; ++k) m.update(NAN);
    EXPECT_EQ(m.windows(), 5);
    EXPECT_THROW(ErrorMonitor(t, x, 0, 0.25, 1e-3, 5), ValueError);
}

}  // namespace
}  // namespace palp::haptics
