#include <gtest/gtest.h>

#include <atomic>
#include <cmath>
#include <cstdlib>
#include <iostream>
#include <limits>
#include <new>
#include <string>

#include "fem_test_util.h"
#include "palp/base/error.h"
#include "palp/base/validate.h"
#include "palp/fem/async_regions.h"
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
// GCC 12 flags free() of operator new's pointer, which is exactly what this pair is.
#pragma GCC diagnostic push
#pragma GCC diagnostic ignored "-Wmismatched-new-delete"
void operator delete(void* p) noexcept { std::free(p); }
void operator delete(void* p, std::size_t) noexcept { std::free(p); }
#pragma GCC diagnostic pop

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

/// The message of the ValueError @p f throws ("" when none).
template <typename F>
std::string refusal(F&& f) {
    try {
        f();
    } catch (const ValueError& e) {
        return e.what();
    }
    return "";
}

/// The number after @p key in @p text.
double numberAfter(const std::string& text, const std::string& key) {
    const auto at = text.find(key);
    EXPECT_NE(at, std::string::npos) << key << " in " << text;
    return at == std::string::npos ? std::nan("") : std::stod(text.substr(at + key.size()));
}

TEST(ExplicitSubsteps, CriticalStepWithStiffnessDampingHasNoCancellation) {
    // dt = 2 / w (sqrt(1 + xi^2) - xi), xi = beta w / 2: for a large xi the difference cancels
    // (it was 0 at beta 1e20); the solver now forms 2 / (w (sqrt(1 + xi^2) + xi)).
    for (const double beta : {0.0, 1e-4, 1e-2, 1.0}) {
        const FemModel model(test::cube13(), test::softTissue(0.0, beta));
        const long double w = model.maxFrequencyBound(), xi = 0.5L * beta * w;
        const long double exact = 2.0L / w * (std::sqrt(1.0L + xi * xi) - xi);
        EXPECT_NEAR(model.criticalTimeStep() / static_cast<double>(exact), 1.0, 1e-12) << beta;
    }
}

TEST(ExplicitSubsteps, TooStiffForTheTickIsRefusedNamingWhatFits) {
    // Soft tissue, 5 mm cells at 1 kHz: a couple of substeps.
    const FemModel soft(test::cube13(), test::softTissue());
    EXPECT_LE(explicitSubstepsPerTick(soft, 0.9, 1e-3), 3.0);
    EXPECT_NO_THROW(requireExplicitSubsteps(soft, 0.9, 4096, 1e-3, "solver.maxSubsteps"));

    // 1 TPa needs ~2.4e4 substeps per 1 ms tick: refused naming the modulus and what fits.
    const FemModel steel(test::cube13(1e12), test::softTissue());
    const double need = explicitSubstepsPerTick(steel, 0.9, 1e-3);
    EXPECT_GT(need, 4096);
    const std::string m =
        refusal([&] { requireExplicitSubsteps(steel, 0.9, 4096, 1e-3, "solver.maxSubsteps"); });
    std::cout << "[ substeps ] " << m << "\n";
    EXPECT_EQ(m.rfind("material youngsModulus: expected at most ", 0), 0u) << m;
    EXPECT_NE(m.find("found 1e+12 Pa (" + formatValue(need) + " substeps per tick)"),
              std::string::npos)
        << m;
    EXPECT_NE(m.find("or raise solver.maxSubsteps"), std::string::npos) << m;
    // The suggestions fit (and only just: 10 % above the modulus does not).
    const double eFit = numberAfter(m, "expected at most ");
    EXPECT_NO_THROW(requireExplicitSubsteps(FemModel(test::cube13(eFit), test::softTissue()), 0.9,
                                            4096, 1e-3, "solver.maxSubsteps"));
    EXPECT_GT(
        explicitSubstepsPerTick(FemModel(test::cube13(1.1 * eFit), test::softTissue()), 0.9, 1e-3),
        4096);
    const double hFit = numberAfter(m, "cells of at least ") * 1e-3;
    const FemModel coarse(HexMesh::box(Eigen::Vector3d::Constant(4 * hFit), {5, 5, 5}, 1e12),
                          test::softTissue());
    EXPECT_LE(explicitSubstepsPerTick(coarse, 0.9, 1e-3), 4096);

    // Stiffness-proportional damping: beta 1 s on soft tissue needs ~4400 substeps.
    const FemModel damped(test::cube13(), test::softTissue(0.0, 1.0));
    const std::string b =
        refusal([&] { requireExplicitSubsteps(damped, 0.9, 1024, 1e-3, "solver.maxSubsteps"); });
    std::cout << "[ substeps ] " << b << "\n";
    EXPECT_EQ(b.rfind("material dampingBeta: expected at most ", 0), 0u) << b;
    EXPECT_NE(b.find("found 1 s ("), std::string::npos) << b;
    const double betaFit = numberAfter(b, "expected at most ");
    EXPECT_NO_THROW(requireExplicitSubsteps(FemModel(test::cube13(), test::softTissue(0, betaFit)),
                                            0.9, 1024, 1e-3, "solver.maxSubsteps"));
    EXPECT_GT(explicitSubstepsPerTick(FemModel(test::cube13(), test::softTissue(0, 1.1 * betaFit)),
                                      0.9, 1e-3),
              1024);
}

TEST(ExplicitSubsteps, SolverBoundsItsSubstepCount) {
    const FemModel model(test::cube13(), test::softTissue());
    const Constraints c = test::bottomFixed(model.mesh());
    ExplicitOptions o;
    o.maxSubsteps = kMaxExplicitSubsteps + 1;
    EXPECT_EQ(refusal([&] { ExplicitSolver(model, c, o); }),
              "explicit solver maxSubsteps: expected a count in [1, 65536], found 65537");
    // A step far longer than the model's critical step runs maxSubsteps stable substeps.
    ExplicitSolver s(model, c);
    const StepResult r = s.step(1e300);
    EXPECT_EQ(r.substeps, 4096);
    EXPECT_EQ(r.flags, kStepSubstepLimit);
}

TEST(ExplicitSubsteps, AsyncRegionsRefuseATickTheirPrimaryCannotStepStably) {
    // The primary used to cap its substeps at maxSubsteps and step above the critical step
    // (unstable, silently); 1 GPa on 5 mm cells needs ~740 substeps per 1 ms tick (> 64).
    const FemModel model(test::cube13(1e9), test::softTissue(60.0));
    const Constraints c = test::bottomFixed(model.mesh());
    AsyncRegionsOptions o;
    const std::string m =
        refusal([&] { AsyncRegions(model, c, {model.mesh().node(6, 6, 12)}, o); });
    std::cout << "[ substeps ] " << m << "\n";
    EXPECT_EQ(m.rfind("material youngsModulus: expected at most ", 0), 0u) << m;
    EXPECT_NE(m.find("or raise async regions maxSubsteps"), std::string::npos) << m;
    o.secondaryRate = 1e-300;
    EXPECT_EQ(refusal([&] { AsyncRegions(model, c, {model.mesh().node(6, 6, 12)}, o); })
                  .rfind("async regions secondary rate: expected a value in [0.000277778, 1000] "
                         "Hz, found 1e-300",
                         0),
              0u);
}

}  // namespace
}  // namespace palp::fem
