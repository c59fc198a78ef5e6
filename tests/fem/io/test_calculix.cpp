#include <gtest/gtest.h>

#include <cfloat>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <iostream>
#include <random>
#include <string>

#include "fem_test_util.h"
#include "palp/base/error.h"
#include "palp/fem/calculix.h"
#include "palp/fem/implicit_solver.h"
#include "test_support.h"

namespace palp::fem {
namespace {

/// Runs `ccx -i job` in @p dir; returns the .dat path.
std::filesystem::path runCcx(const palp::test::TempDir& dir) {
    const auto r = palp::test::runCommand("cd '" + dir.path().string() +
                                          "' && OMP_NUM_THREADS=1 ccx -i job 2>&1");
    EXPECT_EQ(r.exitCode, 0) << r.output;
    return dir / "job.dat";
}

TEST(Calculix, StaticPatchLoadOnTheSoftCubeMatchesCcx) {
    if (!palp::test::haveProgram("ccx")) GTEST_SKIP() << "ccx (Debian calculix-ccx) not installed";
    const FemModel model(test::cube13(), test::softTissue());
    const Constraints c = test::bottomFixed(model.mesh());
    const Eigen::VectorXd load = test::topPatchLoad(model.mesh(), 0.05, 0.0101);
    palp::test::TempDir dir;
    writeCalculixInput(dir / "job.inp", model, c, load, CalculixStep{});
    const CalculixResults ccx = readCalculixDat(runCcx(dir), model.dofCount());
    ASSERT_EQ(ccx.times.size(), 1u);

    ImplicitSolver s(model, c, {Integrator::quasiStatic, LinearSolverKind::cholmod});
    s.externalForce() = load;
    s.step(1.0);
    const double largest = ccx.displacements[0].cwiseAbs().maxCoeff();
    const double worst = (s.displacement() - ccx.displacements[0]).cwiseAbs().maxCoeff();
    std::cout << "[ ccx static ] largest displacement " << largest << " m, worst nodal difference "
              << 100 * worst / largest << " % of it\n";
    EXPECT_GT(largest, 1e-4);
    EXPECT_LT(worst, 0.005 * largest);
}

TEST(Calculix, DampedStepLoadNewmarkMatchesCcxDynamic) {
    // What can be matched: the same mesh, C3D8 stiffness, Rayleigh damping alpha M + beta K
    // (ccx *DAMPING), average-acceleration Newmark (ccx *DYNAMIC with ALPHA=0 switches the HHT
    // dissipation off) and the same fixed increment. What cannot: ccx uses a consistent mass
    // matrix, palp a lumped one, so the frequencies differ by a few per cent and the transient
    // drifts in phase; the settled (static) response is mass-independent and must agree to 1 %,
    // the first peak (amplitude, sampled at the same instants) to 5 %. A 7^3-node cube keeps
    // ccx at about 2 s: it refactorises twice per increment (its nonlinear iteration path).
    if (!palp::test::haveProgram("ccx")) GTEST_SKIP() << "ccx (Debian calculix-ccx) not installed";
    const HexMesh mesh = HexMesh::box(Eigen::Vector3d::Constant(0.06), {7, 7, 7}, 5e3);
    const FemModel model(mesh, test::softTissue(20.0, 5e-4));
    const Constraints c = test::bottomFixed(mesh);
    const Eigen::VectorXd load = test::topPatchLoad(mesh, 0.05, 0.0101);
    const double dt = 5e-3, total = 0.5;
    const int steps = static_cast<int>(std::lround(total / dt));
    palp::test::TempDir dir;
    CalculixStep step;
    step.dynamic = true;
    step.timeIncrement = dt;
    step.totalTime = total;
    writeCalculixInput(dir / "job.inp", model, c, load, step);
    const CalculixResults ccx = readCalculixDat(runCcx(dir), model.dofCount());
    ASSERT_EQ(static_cast<int>(ccx.times.size()), steps);

    ImplicitSolver s(model, c, {Integrator::newmark, LinearSolverKind::cholmod});
    s.externalForce() = load;
    const int probe = 3 * mesh.node(3, 3, 6) + 2;
    double peakPalp = 0.0, peakCcx = 0.0;
    for (int i = 0; i < steps; ++i) {
        ASSERT_EQ(s.step(dt).flags, kStepOk);
        EXPECT_NEAR(ccx.times[static_cast<std::size_t>(i)], (i + 1) * dt, 1e-9);
        peakPalp = std::min(peakPalp, s.displacement()[probe]);
        peakCcx = std::min(peakCcx, ccx.displacements[static_cast<std::size_t>(i)][probe]);
    }
    ImplicitSolver st(model, c, {Integrator::quasiStatic, LinearSolverKind::cholmod});
    st.externalForce() = load;
    ASSERT_EQ(st.step(1.0).flags, kStepOk);
    const double settledCcx = ccx.displacements.back()[probe];
    const double settledPalp = s.displacement()[probe];
    std::cout << "[ ccx dynamic ] static " << st.displacement()[probe] << " m; settled palp "
              << settledPalp << " ccx " << settledCcx << " ("
              << 100 * (settledPalp / settledCcx - 1) << " %); first peak palp " << peakPalp
              << " ccx " << peakCcx << " (" << 100 * (peakPalp / peakCcx - 1) << " %)\n";
    EXPECT_NEAR(settledPalp, settledCcx, 0.01 * std::abs(settledCcx));
    EXPECT_NEAR(settledPalp, st.displacement()[probe], 0.01 * std::abs(settledCcx))
        << "settled means at the static solution";
    EXPECT_NEAR(peakPalp, peakCcx, 0.05 * std::abs(peakCcx));
    EXPECT_LT(peakCcx, 1.2 * settledCcx) << "the load must produce a clear overshoot";
}

TEST(Calculix, ExportAndReaderRejectBadInput) {
    const FemModel model(test::cube13(), test::softTissue());
    palp::test::TempDir dir;
    EXPECT_THROW(writeCalculixInput(dir / "x.inp", model, Constraints(3), Eigen::VectorXd(3),
                                    CalculixStep{}),
                 ValueError);
    EXPECT_THROW(readCalculixDat(dir / "missing.dat", 9), IoError);
}

/// The message of the ValueError @p f throws ("" when it throws none).
template <typename F>
std::string refusal(F&& f) {
    try {
        f();
    } catch (const ValueError& e) {
        return e.what();
    }
    return "";
}

/// Parses @p s as ccx would see it: its first kCalculixNumberWidth characters, all of them a
/// number.
double readBack(const std::string& s) {
    const std::string field = s.substr(0, kCalculixNumberWidth);
    char* end = nullptr;
    const double v = std::strtod(field.c_str(), &end);
    EXPECT_EQ(static_cast<std::size_t>(end - field.c_str()), s.size()) << s;
    return v;
}

TEST(CalculixNumber, ShortestRoundTripWithACompactExponent) {
    EXPECT_EQ(calculixNumber(6.25e-5), "6.25e-5");  // was 6.2500000000000001e-05: ccx error
    EXPECT_EQ(calculixNumber(4.444444444444445e-06), "4.444444444444445e-6");  // was cut at 20
    EXPECT_EQ(calculixNumber(-0.035000000000000003), "-0.035");
    EXPECT_EQ(calculixNumber(1e6), "1e6");
    EXPECT_EQ(calculixNumber(-1e-12), "-1e-12");
    EXPECT_EQ(calculixNumber(5000.0), "5e3");
    EXPECT_EQ(calculixNumber(0.45), "0.45");
    EXPECT_EQ(calculixNumber(0.0), "0");
    EXPECT_EQ(calculixNumber(1e300), "1e300");
    // The worst case: negative, 17 digits, a three-digit exponent: 13 significant digits fit.
    EXPECT_EQ(calculixNumber(-2.2250738585072014e-308), "-2.225073858507e-308");
    EXPECT_EQ(calculixNumber(-DBL_MAX), "-1.7976931348623e308");
    EXPECT_EQ(calculixNumber(-5e-324), "-5e-324");  // the smallest subnormal
    // 17 digits, one-digit exponent: 16 fit for a positive number, 15 for a negative one.
    EXPECT_EQ(calculixNumber(0.1 + 0.2), "0.30000000000000004");
    EXPECT_EQ(calculixNumber(-(0.1 + 0.2)), "-0.30000000000000004");
    EXPECT_EQ(calculixNumber(1.0000000000000002e-5), "1.000000000000000e-5");
    EXPECT_EQ(calculixNumber(-1.0000000000000002e-5), "-1.00000000000000e-5");
    for (const double bad : {std::nan(""), HUGE_VAL, -HUGE_VAL}) {
        EXPECT_EQ(
            refusal([&] { calculixNumber(bad); }).rfind("CalculiX number: expected a finite", 0),
            0u);
    }
}

TEST(CalculixNumber, EveryDoubleFitsAndReadsBackExactlyWhere17DigitsFit) {
    // Random bit patterns (every exponent, subnormals included) and random short decimals.
    std::mt19937_64 rng(20);
    std::uniform_int_distribution<int> digits(1, 17), exponent(-30, 30);
    int exact = 0, rounded = 0;
    double worst = 0;
    for (int i = 0; i < 200000; ++i) {
        double v;
        if (i % 2 == 0) {
            const std::uint64_t bits = rng();
            std::memcpy(&v, &bits, sizeof v);
            if (!std::isfinite(v)) continue;
        } else {
            char text[64];
            std::snprintf(text, sizeof text, "%.*e", digits(rng) - 1,
                          std::ldexp(static_cast<double>(rng() >> 11), -53) *
                              std::pow(10.0, exponent(rng)) * (rng() % 2 ? -1 : 1));
            v = std::strtod(text, nullptr);
        }
        const std::string s = calculixNumber(v);
        ASSERT_LE(s.size(), kCalculixNumberWidth) << s;
        const double back = readBack(s);
        char full[64];  // 17 significant digits always round-trip
        std::snprintf(full, sizeof full, "%.16e", v);
        const std::string text = full;  // its length with a compact exponent:
        const auto e = text.find('e');
        const int exp10 = std::atoi(text.c_str() + e + 1);
        const std::size_t width17 =
            e + 1 + (exp10 < 0 ? 1u : 0u) + std::to_string(std::abs(exp10)).size();
        if (width17 <= kCalculixNumberWidth) {
            ASSERT_EQ(back, v) << s << " for " << full;
            ++exact;
        } else if (back == v) {
            ++exact;  // fewer digits than 17 were enough
        } else {
            const double rel = std::abs(back - v) / std::abs(v);
            worst = std::max(worst, rel);
            ASSERT_LE(rel, 5e-13) << s << " for " << full;  // 13 significant digits
            ++rounded;
        }
    }
    std::cout << "[ calculixNumber ] " << exact << " exact, " << rounded
              << " rounded (worst relative error " << worst << ")\n";
    EXPECT_GT(exact, 100000);
    EXPECT_GT(rounded, 0);
}

TEST(Calculix, ExportRefusesNonFiniteInputNamingTheFieldAndLeavesNoFile) {
    const FemModel model(HexMesh::box(Eigen::Vector3d::Constant(0.02), {3, 3, 3}, 5e3),
                         test::softTissue());
    palp::test::TempDir dir;
    const auto path = dir / "job.inp";
    Constraints c = test::bottomFixed(model.mesh());
    Eigen::VectorXd f = Eigen::VectorXd::Zero(model.dofCount());
    f[3 * 26 + 2] = std::nan("");
    EXPECT_EQ(refusal([&] { writeCalculixInput(path, model, c, f, {}); }),
              "CalculiX export nodalForce dof 80 (node 26, z): expected a finite force in N, "
              "found nan");
    f[3 * 26 + 2] = -HUGE_VAL;
    EXPECT_NE(refusal([&] { writeCalculixInput(path, model, c, f, {}); }).find("found -inf"),
              std::string::npos);
    f.setZero();
    c.setValue(1, HUGE_VAL);
    EXPECT_EQ(refusal([&] { writeCalculixInput(path, model, c, f, {}); }),
              "CalculiX export constraint value of dof 1 (node 0, y): expected a finite "
              "displacement in m, found inf");
    c.setValue(1, 0.0);
    CalculixStep step;
    step.dynamic = true;
    step.timeIncrement = std::nan("");
    EXPECT_EQ(refusal([&] { writeCalculixInput(path, model, c, f, step); }),
              "CalculiX export step.timeIncrement: expected a value in (0, 3600] s, found nan");
    step.timeIncrement = 1e-300;
    EXPECT_NE(refusal([&] {
                  writeCalculixInput(path, model, c, f, step);
              }).find("step.totalTime / step.timeIncrement: expected at most 1e+07"),
              std::string::npos);
    step.timeIncrement = 1e-3;
    step.totalTime = HUGE_VAL;
    EXPECT_NE(refusal([&] {
                  writeCalculixInput(path, model, c, f, step);
              }).find("step.totalTime: expected"),
              std::string::npos);
    EXPECT_FALSE(std::filesystem::exists(path));
    EXPECT_TRUE(std::filesystem::is_empty(dir.path())) << "no temporary left either";
    step.totalTime = 0.01;
    writeCalculixInput(path, model, c, f, step);
    EXPECT_TRUE(std::filesystem::exists(path));
}

TEST(Calculix, AwkwardLoadsRoundTripThroughCcx) {
    // Each load is written on the nine top-centre nodes of a 5^3-node cube as it is; ccx's
    // displacements must equal palp's static solve to ccx's print precision (it prints 7
    // significant digits). Before the fix 6.25e-5 stopped ccx (*ERROR reading *CLOAD) and
    // 4.444444444444445e-06 was cut to 20 characters and read as ~4.4.
    if (!palp::test::haveProgram("ccx")) GTEST_SKIP() << "ccx (Debian calculix-ccx) not installed";
    // An origin off zero so coordinates are negative and awkward too.
    const HexMesh mesh = HexMesh::box(Eigen::Vector3d::Constant(0.04), {5, 5, 5}, 5e3,
                                      Eigen::Vector3d(-0.0333, -0.0217, -0.0151));
    const FemModel model(mesh, test::softTissue());
    const Constraints c = test::bottomFixed(mesh);
    ImplicitSolver s(model, c, {Integrator::quasiStatic, LinearSolverKind::cholmod});
    for (const double load : {6.25e-5, 4.444444444444445e-06, -3.3333333333333335e-07,
                              -0.30000000000000004, 1e-12, 1e6, -1.2345678901234567e6}) {
        Eigen::VectorXd f = Eigen::VectorXd::Zero(model.dofCount());
        for (int i = 1; i <= 3; ++i) {
            for (int j = 1; j <= 3; ++j) {
                f[3 * mesh.node(i, j, 4) + 2] = load;
                f[3 * mesh.node(i, j, 4)] = 0.5 * load;
            }
        }
        palp::test::TempDir dir;
        writeCalculixInput(dir / "job.inp", model, c, f, CalculixStep{});
        const CalculixResults ccx = readCalculixDat(runCcx(dir), model.dofCount());
        ASSERT_EQ(ccx.times.size(), 1u) << "load " << load;
        s.externalForce() = f;
        ASSERT_EQ(s.step(1.0).flags, kStepOk);
        const double largest = s.displacement().cwiseAbs().maxCoeff();
        const double worst = (s.displacement() - ccx.displacements[0]).cwiseAbs().maxCoeff();
        std::cout << "[ ccx load " << calculixNumber(load) << " N ] largest displacement "
                  << largest << " m, worst nodal difference " << worst / largest << " of it\n";
        EXPECT_GT(largest, 0.0);
        EXPECT_LT(worst, 1e-6 * largest) << "load " << load;
    }
}

}  // namespace
}  // namespace palp::fem
