#include "regions/async_setup.h"

#include <algorithm>
#include <cmath>
#include <string>

#include "index_cast.h"
#include "palp/base/bounds.h"
#include "palp/base/validate.h"
#include "palp/fem/explicit_solver.h"

namespace palp::fem {

namespace {

[[noreturn]] void fail(const std::string& what, const std::string& expected, double found) {
    throwExpected("async regions " + what, expected, formatValue(found));
}
[[noreturn]] void fail(const std::string& what, const std::string& expected, int found) {
    throwExpected("async regions " + what, expected, std::to_string(found));
}
[[noreturn]] void fail(const std::string& what, const std::string& expected, const char* found) {
    throwExpected("async regions " + what, expected, found);
}

}  // namespace

NewmarkCoefficients newmarkCoefficients(Integrator integrator, double dt) {
    NewmarkCoefficients c;
    if (integrator == Integrator::newmark) {
        constexpr double beta = 0.25, gamma = 0.5;
        c.a0 = 1.0 / (beta * dt * dt);
        c.a1 = gamma / (beta * dt);
        c.a2 = 1.0 / (beta * dt);
        c.a3 = 1.0 / (2.0 * beta) - 1.0;
        c.a4 = gamma / beta - 1.0;
        c.a5 = dt * (gamma / (2.0 * beta) - 1.0);
    } else if (integrator == Integrator::backwardEuler) {
        c.a0 = 1.0 / (dt * dt);
        c.a1 = 1.0 / dt;
        c.a2 = 1.0 / dt;
    }
    return c;
}

AsyncSetup::AsyncSetup(const FemModel& m, const Constraints& c, const std::vector<int>& contact,
                       const AsyncRegionsOptions& o)
    : model(m), options(o) {
    const HexMesh& mesh = model.mesh();
    const int dofs = model.dofCount();
    if (c.dofCount() != dofs) fail("constraints", std::to_string(dofs) + " dofs", c.dofCount());
    // A neo-Hookean model: TLED in the primary (large strain where the finger is), the linear
    // small-strain stiffness in the secondary (the condensed coupling and the layouts need a
    // linear far field).
    if (model.material().law == MaterialLaw::neoHookean)
        tled = std::make_shared<const TledForces>(model, o.tled);
    if (!bounds::kPeriod.contains(o.tickSeconds))
        fail("tick", describe(bounds::kPeriod), o.tickSeconds);
    // At least one solve an hour (the period stays an honest tick count), at most 1 kHz.
    if (!(o.secondaryRate >= 1.0 / bounds::kDuration.max &&
          o.secondaryRate <= bounds::kFrequency.max))
        fail("secondary rate",
             describe({1.0 / bounds::kDuration.max, bounds::kFrequency.max, "Hz"}),
             o.secondaryRate);
    if (o.lod != 1 && o.lod != 2 && o.lod != 4) fail("lod", "1, 2 or 4", o.lod);
    if (!(o.plainLead <= 1.0)) fail("plain lead", "a value <= 1", o.plainLead);
    if (!(o.safetyFactor > 0.0 && o.safetyFactor <= 1.0))
        fail("safety factor", "a value in (0, 1]", o.safetyFactor);
    if (o.maxSubsteps < 1 || o.maxSubsteps > kMaxExplicitSubsteps)
        fail("max substeps", "a count in [1, " + std::to_string(kMaxExplicitSubsteps) + "]",
             o.maxSubsteps);
    if (o.secondaryThreads < 1) fail("secondary threads", ">= 1", o.secondaryThreads);
    if (o.secondarySolver == LinearSolverKind::simplicialLdlt)
        fail("secondary solver", "cholmod or pcg", "simplicialLdlt");
    if (contact.empty()) fail("contact nodes", "at least one node", "none");
    if (o.maxLoads < 1) fail("max loads", ">= 1", o.maxLoads);
    // The primary's substeps: a model too stiff for maxSubsteps per tick is refused here (a
    // capped substep above the critical one would run unstable).
    requireExplicitSubsteps(model, o.safetyFactor, o.maxSubsteps, o.tickSeconds,
                            "async regions maxSubsteps");
    forceDrive = o.drive == ContactDrive::force;
    watchIndex.assign(sz(mesh.nodeCount()), -1);
    for (std::size_t i = 0; i < o.watchNodes.size(); ++i) {
        const int n = o.watchNodes[i];
        if (n < 0 || n >= mesh.nodeCount() || !mesh.nodeActive()[sz(n)])
            fail("watch node", "an active node of the mesh", n);
        if (watchIndex[sz(n)] >= 0) fail("watch node", "distinct nodes", n);
        watchIndex[sz(n)] = static_cast<int>(i);
    }
    for (int n : contact) {
        if (n < 0 || n >= mesh.nodeCount() || !mesh.nodeActive()[sz(n)])
            fail("contact node", "an active node of the mesh", n);
    }
    if (o.primaryNodes < static_cast<int>(contact.size()))
        fail("primary nodes", ">= the number of contact nodes", o.primaryNodes);
    adaptive = o.maxPrimaryNodes > o.primaryNodes;
    if (adaptive && o.threaded) fail("adaptive primary", "synchronous mode", "threaded mode");
    if (adaptive &&
        (o.adaptiveLevels < 2 || !(o.strainAtMax > 0.0) || !(o.strainReferenceLength > 0.0)))
        fail("adaptive primary", "levels >= 2 and positive strain scales", o.adaptiveLevels);
    lod = o.lod;
    for (int a = 0; a < 3; ++a) {
        const int cells = mesh.nodeCounts()[sz(a)] - 1;
        if (cells % lod != 0) fail("lod", "a factor of every cell count", cells);
        coarseCounts[sz(a)] = cells / lod + 1;
    }
    coarseDofs = 3 * coarseCounts[0] * coarseCounts[1] * coarseCounts[2];

    fixed.assign(sz(dofs), 0);
    nonZeroPrescribed.assign(sz(mesh.nodeCount()), 0);
    for (int d = 0; d < dofs; ++d) {
        fixed[sz(d)] = c.isFixed(d) ? 1 : 0;
        if (c.isFixed(d) && c.values()[d] != 0.0) nonZeroPrescribed[sz(d / 3)] = 1;
    }
    watchPlain.assign(o.watchNodes.size(), 1);
    for (std::size_t i = 0; i < o.watchNodes.size(); ++i) {
        if (!mesh.nodeActive()[sz(o.watchNodes[i])]) watchPlain[i] = 0;
        for (int k = 0; k < 3; ++k) {
            if (fixed[sz(3 * o.watchNodes[i] + k)]) {
                watchFixedDofs.push_back(3 * static_cast<int>(i) + k);
                watchPlain[i] = 0;
            }
        }
    }

    period = std::max(1, static_cast<int>(std::lround(1.0 / (o.secondaryRate * o.tickSeconds))));
    periodSeconds = period * o.tickSeconds;
    if (o.secondaryIntegrator == Integrator::quasiStatic) {
        sK = 1.0;
        sM = 0.0;
    } else {
        nm = newmarkCoefficients(o.secondaryIntegrator, periodSeconds);
        sK = 1.0 + nm.a1 * model.material().dampingBeta;
        sM = nm.a0 + nm.a1 * model.material().dampingAlpha;
    }
}

double AsyncSetup::periodFraction(double time, double start) const noexcept {
    return options.interpolate ? std::clamp((time - start) / periodSeconds, 0.0, 1.0) : 1.0;
}

}  // namespace palp::fem
