// FEM step benchmarks: palp's element-by-element explicit step against a plain CSR SpMV
// central-difference reference step in the same run, implicit steps, assembly, factorisation.
#include <benchmark/benchmark.h>

#include <random>

#include "palp/fem/explicit_solver.h"
#include "palp/fem/fem_model.h"
#include "palp/fem/implicit_solver.h"
#include "palp/fem/tled.h"

namespace {

using namespace palp::fem;

ElasticMaterial tissue() { return ElasticMaterial{5e3, 0.45, 1e3, 0.0, 0.0}; }

/// Cube of n^3 nodes, h = 5 mm; inhomogeneous: per-element E uniform in [2, 20] kPa.
HexMesh cube(int n, bool inhomogeneous) {
    const int cells = (n - 1) * (n - 1) * (n - 1);
    std::vector<double> e(static_cast<std::size_t>(cells), 5e3);
    if (inhomogeneous) {
        std::mt19937 rng(1);
        std::uniform_real_distribution<double> u(2e3, 2e4);
        for (auto& v : e) v = u(rng);
    }
    return HexMesh::fromCells({n, n, n}, 0.005, Eigen::Vector3d::Zero(), e);
}

Constraints bottom(const HexMesh& m) {
    Constraints c(m.dofCount());
    c.fixNodes(m.faceNodes(BoxFace::zMin));
    return c;
}

void setLabel(benchmark::State& state, const FemModel& model) {
    state.counters["dofs"] = model.dofCount();
    state.counters["elements"] = model.mesh().elementCount();
}

/// Reference: u(n+1) = (dt^2 (f - K u) + 2 M u - M u(n-1)) / M with K in CSR (row-major),
/// a straightforward SpMV, constrained dofs held at zero.
void BM_ReferenceCsrStep(benchmark::State& state) {
    const FemModel model(cube(static_cast<int>(state.range(0)), state.range(1) != 0), tissue());
    const Constraints c = bottom(model.mesh());
    const Eigen::SparseMatrix<double, Eigen::RowMajor, int> k = model.assembleStiffness();
    const Eigen::VectorXd& m = model.lumpedMass();
    const int n = model.dofCount();
    const double dt = 0.9 * model.criticalTimeStep();
    Eigen::VectorXd u = Eigen::VectorXd::Zero(n), up = u, f = Eigen::VectorXd::Zero(n);
    std::vector<double> invM(static_cast<std::size_t>(n));
    for (int d = 0; d < n; ++d) {
        invM[static_cast<std::size_t>(d)] = (c.isFixed(d) || m[d] <= 0) ? 0.0 : 1.0 / m[d];
        f[d] = 1e-6;
    }
    const int* outer = k.outerIndexPtr();
    const int* inner = k.innerIndexPtr();
    const double* val = k.valuePtr();
    for (auto _ : state) {
        for (int i = 0; i < n; ++i) {
            double ku = 0.0;
            for (int p = outer[i]; p < outer[i + 1]; ++p) ku += val[p] * u[inner[p]];
            const double mi = invM[static_cast<std::size_t>(i)];
            up[i] = mi == 0.0 ? 0.0 : 2.0 * u[i] - up[i] + dt * dt * (f[i] - ku) * mi;
        }
        u.swap(up);
        benchmark::DoNotOptimize(u.data());
    }
    setLabel(state, model);
}

void BM_ExplicitStep(benchmark::State& state) {
    const FemModel model(cube(static_cast<int>(state.range(0)), state.range(1) != 0), tissue());
    ExplicitSolver s(model, bottom(model.mesh()));
    s.externalForce().setConstant(1e-6);
    const double dt = s.stableTimeStep();
    for (auto _ : state) {
        s.step(dt);
        benchmark::DoNotOptimize(s.displacement().data());
    }
    setLabel(state, model);
}

/// The matrix-free operator alone: f = K u (zeroing f included), one thread.
void BM_StiffnessOperator(benchmark::State& state) {
    const FemModel model(cube(static_cast<int>(state.range(0)), state.range(1) != 0), tissue());
    Eigen::VectorXd u = Eigen::VectorXd::Constant(model.dofCount(), 1e-4), f = u;
    for (auto _ : state) {
        f.setZero();
        model.addStiffnessTimes(u.data(), f.data());
        benchmark::DoNotOptimize(f.data());
    }
    setLabel(state, model);
}

/// The TLED internal force alone (neo-Hookean, palp/fem/tled.h) on the same cube, one thread:
/// f = f_int(u) (zeroing f included) of a random 1 % strain state; arg 1: 0 one point with
/// hourglass control, 1 2x2x2 Gauss. Compare with BM_StiffnessOperator/13/0 per element.
void BM_TledForces(benchmark::State& state) {
    ElasticMaterial m = tissue();
    m.law = MaterialLaw::neoHookean;
    const FemModel model(cube(static_cast<int>(state.range(0)), false), m);
    const TledForces tled(model, {state.range(1) != 0 ? TledIntegration::gauss2x2x2
                                                      : TledIntegration::onePointHourglass,
                                  0.1});
    std::mt19937 rng(2);
    std::uniform_real_distribution<double> jitter(-5e-5, 5e-5);  // 1 % of the 5 mm cells
    Eigen::VectorXd u(model.dofCount()), f = Eigen::VectorXd::Zero(model.dofCount());
    for (int d = 0; d < u.size(); ++d) u[d] = jitter(rng);
    for (auto _ : state) {
        f.setZero();
        tled.addInternalForces(u.data(), f.data());
        benchmark::DoNotOptimize(f.data());
    }
    setLabel(state, model);
}

void BM_ExplicitStepTbb(benchmark::State& state) {
    const FemModel model(cube(static_cast<int>(state.range(0)), state.range(1) != 0), tissue());
    ExplicitSolver s(model, bottom(model.mesh()));
    s.externalForce().setConstant(1e-6);
    const double dt = s.stableTimeStep();
    for (auto _ : state) {
        s.stepParallel(dt);
        benchmark::DoNotOptimize(s.displacement().data());
    }
    setLabel(state, model);
}

void BM_ImplicitStep(benchmark::State& state) {
    const FemModel model(cube(static_cast<int>(state.range(0)), false), tissue());
    const auto kind = static_cast<LinearSolverKind>(state.range(1));
    ImplicitSolver s(model, bottom(model.mesh()), {Integrator::newmark, kind, 1e-8, 5000});
    s.externalForce().setConstant(1e-6);
    s.step(1e-3);  // factorise once
    for (auto _ : state) {
        s.step(1e-3);
        benchmark::DoNotOptimize(s.displacement().data());
    }
    state.counters["cg_iterations"] = s.lastIterations();
    setLabel(state, model);
}

void BM_Assembly(benchmark::State& state) {
    const FemModel model(cube(static_cast<int>(state.range(0)), true), tissue());
    for (auto _ : state) {
        SparseMatrix k = model.assembleStiffness();
        benchmark::DoNotOptimize(k.valuePtr());
    }
    setLabel(state, model);
}

void BM_Factorisation(benchmark::State& state) {
    const FemModel model(cube(static_cast<int>(state.range(0)), false), tissue());
    const auto kind = static_cast<LinearSolverKind>(state.range(1));
    const Constraints c = bottom(model.mesh());
    for (auto _ : state) {
        // Constructing a quasi-static solver assembles, checks supports and factorises.
        ImplicitSolver s(model, c, {Integrator::quasiStatic, kind});
        benchmark::DoNotOptimize(&s);
    }
    setLabel(state, model);
}

// Args: nodes per edge, inhomogeneous (0/1).
BENCHMARK(BM_ReferenceCsrStep)
    ->Args({13, 0})
    ->Args({13, 1})
    ->Args({33, 0})
    ->Unit(benchmark::kMicrosecond);
BENCHMARK(BM_ExplicitStep)
    ->Args({13, 0})
    ->Args({13, 1})
    ->Args({33, 0})
    ->Args({33, 1})
    ->Unit(benchmark::kMicrosecond);
BENCHMARK(BM_StiffnessOperator)->Args({13, 0})->Args({13, 1})->Unit(benchmark::kMicrosecond);
BENCHMARK(BM_TledForces)->Args({13, 0})->Args({13, 1})->Unit(benchmark::kMicrosecond);
BENCHMARK(BM_ExplicitStepTbb)->Args({13, 0})->Args({33, 0})->Unit(benchmark::kMicrosecond);
// Args: nodes per edge, solver (0 LDLT, 1 CHOLMOD, 2 PCG).
BENCHMARK(BM_ImplicitStep)
    ->Args({13, 0})
    ->Args({13, 1})
    ->Args({13, 2})
    ->Unit(benchmark::kMillisecond);
BENCHMARK(BM_Assembly)->Arg(13)->Arg(33)->Unit(benchmark::kMillisecond);
BENCHMARK(BM_Factorisation)->Args({13, 0})->Args({13, 1})->Unit(benchmark::kMillisecond);

}  // namespace

BENCHMARK_MAIN();
