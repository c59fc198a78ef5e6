#include <gtest/gtest.h>

#include <atomic>
#include <cmath>
#include <cstdlib>
#include <limits>
#include <new>

#include "fem_test_util.h"
#include "palp/base/error.h"
#include "palp/fem/explicit_solver.h"
#include "palp/fem/implicit_solver.h"

// A counting global operator new: the real-time step must not allocate.
namespace {
std::atomic<bool> gCountAllocations{false};
std::atomic<long> gAllocations{0};
}  // namespace

void* operator new(std::size_t size) {
    if (gCountAllocations.load(std::memory_order_relaxed)) gAllocations.fetch_add(1);
    if (void* p = std::malloc(size == 0 ? 1 : size)) return p;
    throw std::bad_alloc();
}
void operator delete(void* p) noexcept { std::free(p); }
void operator delete(void* p, std::size_t) noexcept { std::free(p); }

namespace palp::fem {
namespace {

/// Static displacement of the cube under a top patch load of @p newtons.
Eigen::VectorXd staticPatchSolution(const FemModel& model, const Constraints& c, double newtons) {
    ImplicitSolver s(model, c, {Integrator::quasiStatic, LinearSolverKind::cholmod});
    s.externalForce() = test::topPatchLoad(model.mesh(), newtons, 0.0101);
    s.step(1.0);
    return s.displacement();
}

TEST(ExplicitSolver, UndampedEnergyIsConservedOver10000Steps) {
    const FemModel model(test::cube13(), test::softTissue());
    const Constraints c = test::bottomFixed(model.mesh());
    ExplicitSolver solver(model, c);
    const Eigen::VectorXd u0 = staticPatchSolution(model, c, 0.05);
    solver.setDisplacement(u0);  // released from rest: free vibration
    const double e0 = model.strainEnergy(u0);
    ASSERT_GT(e0, 0.0);
    const double dt = solver.stableTimeStep();
    double worst = 0.0, minStrain = e0;
    for (int s = 0; s < 10000; ++s) {
        const StepResult r = solver.step(dt);
        ASSERT_EQ(r.substeps, 1);
        const double total = solver.kineticEnergy() + solver.strainEnergy();
        worst = std::max(worst, std::abs(total - e0) / e0);
        minStrain = std::min(minStrain, solver.strainEnergy());
    }
    EXPECT_LT(worst, 0.01) << "relative energy drift over 10000 steps";
    EXPECT_LT(minStrain, 0.2 * e0) << "the body must actually oscillate";
    std::cout << "[ energy ] 10000 steps of " << dt * 1e3 << " ms: max relative error " << worst
              << "\n";
}

TEST(ExplicitSolver, LargeRequestedStepIsSubsteppedNotDiverging) {
    const FemModel model(test::cube13(), test::softTissue());
    const Constraints c = test::bottomFixed(model.mesh());
    ExplicitSolver solver(model, c);
    const Eigen::VectorXd u0 = staticPatchSolution(model, c, 0.05);
    solver.setDisplacement(u0);
    const double e0 = model.strainEnergy(u0);
    const double request = 25.3 * solver.stableTimeStep();
    for (int s = 0; s < 40; ++s) {
        const StepResult r = solver.step(request);
        EXPECT_EQ(r.substeps, 26);
        EXPECT_EQ(r.flags, kStepOk);
        EXPECT_NEAR(r.advancedSeconds, request, 1e-15);
        EXPECT_LE(solver.lastSubstep(), solver.stableTimeStep());
    }
    EXPECT_TRUE(solver.displacement().allFinite());
    EXPECT_LT(solver.kineticEnergy() + solver.strainEnergy(), 1.01 * e0);
    // A substep limit is flagged and the solver advances only what is stable.
    ExplicitOptions limited;
    limited.maxSubsteps = 4;
    ExplicitSolver capped(model, c, limited);
    capped.setDisplacement(u0);
    const StepResult r = capped.step(request);
    EXPECT_EQ(r.flags & kStepSubstepLimit, kStepSubstepLimit);
    EXPECT_EQ(r.substeps, 4);
    EXPECT_NEAR(r.advancedSeconds, 4 * capped.stableTimeStep(), 1e-15);
    EXPECT_TRUE(capped.displacement().allFinite());
}

TEST(ExplicitSolver, RealTimeStepDoesNotAllocate) {
    const FemModel model(test::cube13(), test::softTissue(5.0, 1e-4));
    Constraints c = test::bottomFixed(model.mesh());
    const int contact = 3 * model.mesh().node(6, 6, 12) + 2;
    c.prescribe(contact, 0.0);
    ExplicitSolver solver(model, c);
    solver.externalForce() = test::topPatchLoad(model.mesh(), 0.02, 0.0101);
    solver.step(1e-3);  // first call may set coefficients: still must not allocate, but warm up
    gAllocations = 0;
    gCountAllocations = true;
    for (int s = 0; s < 20; ++s) {
        solver.setPrescribed(contact, -1e-4 * s);
        solver.step(1e-3);
        (void)solver.strainEnergy();
    }
    gCountAllocations = false;
    EXPECT_EQ(gAllocations.load(), 0);
    EXPECT_NEAR(solver.displacement()[contact], -1.9e-3, 1e-15);
    EXPECT_TRUE(std::isfinite(solver.reaction(contact)));
}

TEST(ExplicitSolver, ParallelStepMatchesSingleThread) {
    const FemModel model(test::cube13(), test::softTissue(2.0, 5e-5));
    const Constraints c = test::bottomFixed(model.mesh());
    ExplicitSolver a(model, c), b(model, c);
    a.externalForce() = test::topPatchLoad(model.mesh(), 0.05, 0.0101);
    b.externalForce() = a.externalForce();
    for (int s = 0; s < 50; ++s) {
        a.step(2e-3);
        b.stepParallel(2e-3);
    }
    EXPECT_LT((a.displacement() - b.displacement()).norm(), 1e-12 * a.displacement().norm());
}

TEST(ExplicitSolver, BadInputIsFlaggedNeverNaN) {
    const FemModel model(test::cube13(), test::softTissue());
    const Constraints c = test::bottomFixed(model.mesh());
    ExplicitSolver solver(model, c);
    EXPECT_EQ(solver.step(0.0).flags, kStepBadTimeStep);
    EXPECT_EQ(solver.step(-1e-3).flags, kStepBadTimeStep);
    EXPECT_EQ(solver.step(std::numeric_limits<double>::quiet_NaN()).flags, kStepBadTimeStep);
    solver.externalForce()[3 * model.mesh().node(6, 6, 12) + 2] =
        std::numeric_limits<double>::infinity();
    const StepResult r = solver.step(1e-3);
    EXPECT_EQ(r.flags & kStepBadForce, kStepBadForce);
    EXPECT_TRUE(solver.displacement().allFinite());
    EXPECT_THROW(ExplicitSolver(model, Constraints(9)), palp::ValueError);
    ExplicitOptions bad;
    bad.safetyFactor = 1.5;
    EXPECT_THROW(ExplicitSolver(model, c, bad), palp::ValueError);
}

TEST(ExplicitSolver, AgreesWithImplicitOnADampedStepLoad) {
    // Rayleigh damping: alpha = 40 /s (zeta ~ 0.6 on the first mode, a clear overshoot remains),
    // beta = 0.2 ms so that Newmark's undissipated high modes (omega dt >> 1) die out too; it
    // shortens the explicit stable step by about 25 %. Both integrators advance 5 ms per call
    // (the explicit one in substeps) and are compared at the same instants; after 0.6 s both
    // sit at the static solution.
    const FemModel model(test::cube13(), test::softTissue(40.0, 2e-4));
    const Constraints c = test::bottomFixed(model.mesh());
    const Eigen::VectorXd load = test::topPatchLoad(model.mesh(), 0.05, 0.0101);
    ExplicitSolver ex(model, c);
    ImplicitSolver im(model, c, {Integrator::newmark, LinearSolverKind::cholmod});
    ex.externalForce() = load;
    im.externalForce() = load;
    const int probe = 3 * model.mesh().node(6, 6, 12) + 2;
    double peakEx = 0.0, peakIm = 0.0;
    const double dt = 5e-3;
    for (int s = 0; s < 120; ++s) {
        ASSERT_EQ(ex.step(dt).flags, kStepOk);
        ASSERT_EQ(im.step(dt).flags, kStepOk);
        peakEx = std::min(peakEx, ex.displacement()[probe]);
        peakIm = std::min(peakIm, im.displacement()[probe]);
    }
    const Eigen::VectorXd uStatic = staticPatchSolution(model, c, 0.05);
    const double scale = uStatic.cwiseAbs().maxCoeff();
    EXPECT_LT((ex.displacement() - uStatic).cwiseAbs().maxCoeff(), 0.01 * scale);
    EXPECT_LT((im.displacement() - uStatic).cwiseAbs().maxCoeff(), 0.01 * scale);
    EXPECT_LT((ex.displacement() - im.displacement()).cwiseAbs().maxCoeff(), 0.01 * scale);
    EXPECT_NEAR(peakEx, peakIm, 0.05 * std::abs(peakIm));
    EXPECT_LT(peakIm, uStatic[probe]);  // a dynamic overshoot happened
    std::cout << "[ step load ] static " << uStatic[probe] << " m, peaks explicit " << peakEx
              << " implicit " << peakIm << "\n";
}

}  // namespace
}  // namespace palp::fem
