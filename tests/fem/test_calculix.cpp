#include <gtest/gtest.h>

#include <cmath>
#include <iostream>

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

}  // namespace
}  // namespace palp::fem
