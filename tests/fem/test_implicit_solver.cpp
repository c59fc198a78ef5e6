#include "palp/fem/implicit_solver.h"

#include <gtest/gtest.h>

#include <cmath>
#include <limits>

#include "fem_test_util.h"
#include "palp/error.h"

namespace palp::fem {
namespace {

/// Uniaxial compression with roller supports: homogeneous stress, F = E A delta / L.
struct Uniaxial {
    HexMesh mesh = test::cube13();
    Constraints c{mesh.dofCount()};
    std::vector<int> top = mesh.faceNodes(BoxFace::zMax);
    double delta = 1e-3;
    Uniaxial() {
        c.fixNodes(mesh.faceNodes(BoxFace::zMin), 4u);    // uz = 0 on the bottom
        c.fixNodes({mesh.node(0, 0, 0)}, 3u);             // no rigid x, y translation
        c.fixNodes({mesh.node(12, 0, 0)}, 2u);            // no rigid rotation about z
        for (int n : top) c.prescribe(3 * n + 2, -delta);
    }
};

TEST(ImplicitSolver, UniaxialCompressionMatchesHookesLaw) {
    Uniaxial p;
    const FemModel model(p.mesh, test::softTissue());
    for (auto kind : {LinearSolverKind::simplicialLdlt, LinearSolverKind::cholmod,
                      LinearSolverKind::pcg}) {
        ImplicitSolver s(model, p.c, {Integrator::quasiStatic, kind});
        EXPECT_EQ(s.step(1.0).flags, kStepOk);
        const double area = 0.06 * 0.06, length = 0.06;
        const double expected = 5e3 * area * p.delta / length;  // 0.3 N
        const double force = -s.reactionSum(p.top).z();
        EXPECT_NEAR(force, expected, 0.01 * expected) << static_cast<int>(kind);
        EXPECT_NEAR(force, expected, 1e-6 * expected) << "homogeneous: exact up to round-off";
        // Lateral expansion: u_x(L) = nu delta.
        EXPECT_NEAR(s.displacement()[3 * p.mesh.node(12, 6, 6)], 0.45 * p.delta, 1e-8);
        // Reactions balance: bottom pushes back with the same force.
        EXPECT_NEAR(s.reactionSum(p.mesh.faceNodes(BoxFace::zMin)).z(), expected, 1e-6 * expected);
    }
}

TEST(ImplicitSolver, DirectAndIterativeSolversAgreeAndReuseTheFactorisation) {
    const FemModel model(test::cube13(), test::softTissue(3.0, 1e-4));
    const Constraints c = test::bottomFixed(model.mesh());
    const Eigen::VectorXd load = test::topPatchLoad(model.mesh(), 0.05, 0.0101);
    std::vector<Eigen::VectorXd> results;
    for (auto kind : {LinearSolverKind::simplicialLdlt, LinearSolverKind::cholmod,
                      LinearSolverKind::pcg}) {
        ImplicitSolver s(model, c, {Integrator::newmark, kind, 1e-12, 5000});
        s.externalForce() = load;
        for (int i = 0; i < 20; ++i) EXPECT_EQ(s.step(2e-3).flags, kStepOk);
        EXPECT_EQ(s.factorisations(), 1) << "matrix unchanged: factorised once";
        if (kind == LinearSolverKind::pcg) {
            EXPECT_GT(s.lastIterations(), 0);
        }
        results.push_back(s.displacement());
    }
    const double scale = results[0].cwiseAbs().maxCoeff();
    EXPECT_GT(scale, 0.0);
    EXPECT_LT((results[1] - results[0]).cwiseAbs().maxCoeff(), 1e-9 * scale);
    EXPECT_LT((results[2] - results[0]).cwiseAbs().maxCoeff(), 1e-7 * scale);
}

TEST(ImplicitSolver, NewmarkAndBackwardEulerSettleToTheStaticSolution) {
    const FemModel model(test::cube13(), test::softTissue(20.0, 0.0));
    const Constraints c = test::bottomFixed(model.mesh());
    const Eigen::VectorXd load = test::topPatchLoad(model.mesh(), 0.05, 0.0101);
    ImplicitSolver st(model, c, {Integrator::quasiStatic, LinearSolverKind::cholmod});
    st.externalForce() = load;
    st.step(1.0);
    const double scale = st.displacement().cwiseAbs().maxCoeff();
    for (auto integ : {Integrator::newmark, Integrator::backwardEuler}) {
        ImplicitSolver s(model, c, {integ, LinearSolverKind::cholmod});
        s.externalForce() = load;
        for (int i = 0; i < 200; ++i) s.step(1e-2);  // dt = 10 stable explicit steps
        EXPECT_LT((s.displacement() - st.displacement()).cwiseAbs().maxCoeff(), 0.01 * scale)
            << "integrator " << static_cast<int>(integ);
        EXPECT_LT(s.kineticEnergy(), 1e-6 * s.strainEnergy());
    }
}

TEST(ImplicitSolver, UnsupportedStaticProblemAndBadStepsAreRejected) {
    const FemModel model(test::cube13(), test::softTissue());
    Constraints none(model.dofCount());
    try {
        ImplicitSolver s(model, none, {Integrator::quasiStatic, LinearSolverKind::simplicialLdlt});
        FAIL() << "expected a ValueError";
    } catch (const ValueError& e) {
        EXPECT_NE(std::string(e.what()).find("rigid-body"), std::string::npos) << e.what();
    }
    // Only uz fixed on the bottom: x/y translations and z-rotation remain free.
    Constraints rollers(model.dofCount());
    rollers.fixNodes(model.mesh().faceNodes(BoxFace::zMin), 4u);
    EXPECT_THROW(ImplicitSolver(model, rollers, {Integrator::quasiStatic}), ValueError);
    // The dynamic problem is well posed without supports (mass regularises it).
    ImplicitSolver dyn(model, none, {Integrator::newmark});
    EXPECT_EQ(dyn.step(0.0).flags, kStepBadTimeStep);
    EXPECT_EQ(dyn.step(-1.0).flags, kStepBadTimeStep);
    dyn.externalForce()[5] = std::numeric_limits<double>::quiet_NaN();
    EXPECT_EQ(dyn.step(1e-3).flags & kStepBadForce, kStepBadForce);
    EXPECT_TRUE(dyn.displacement().allFinite());
}

/// Quarter model of a rigid frictionless flat punch of radius a on a block.
double punchForce(int nodesPerEdge, double block, double radius, double delta) {
    const HexMesh mesh = HexMesh::box(Eigen::Vector3d::Constant(block),
                                      {nodesPerEdge, nodesPerEdge, nodesPerEdge}, 5e3);
    const FemModel model(mesh, test::softTissue());
    Constraints c(mesh.dofCount());
    c.fixNodes(mesh.faceNodes(BoxFace::xMin), 1u);  // symmetry planes
    c.fixNodes(mesh.faceNodes(BoxFace::yMin), 2u);
    c.fixNodes(mesh.faceNodes(BoxFace::zMin), 7u);  // block bonded to a rigid base
    std::vector<int> punch;
    for (int n : mesh.faceNodes(BoxFace::zMax)) {
        const Eigen::Vector3d p = mesh.nodePosition(n);
        if (std::hypot(p.x(), p.y()) <= radius * (1 + 1e-9)) punch.push_back(n);
    }
    for (int n : punch) c.prescribe(3 * n + 2, -delta);
    ImplicitSolver s(model, c, {Integrator::quasiStatic, LinearSolverKind::cholmod});
    s.step(1.0);
    return -4.0 * s.reactionSum(punch).z();
}

TEST(ImplicitSolver, FlatPunchConvergesToSneddon) {
    const double e = 5e3, nu = 0.45, a = 0.01, delta = 1e-4, block = 0.08;
    const double sneddon = 2.0 * a * e * delta / (1.0 - nu * nu);
    double previousError = 1e9;
    for (int n : {9, 17, 33}) {
        const double f = punchForce(n, block, a, delta);
        const double error = f / sneddon - 1.0;
        std::cout << "[ Sneddon ] h = " << block / (n - 1) * 1e3 << " mm, a/h = "
                  << a / (block / (n - 1)) << ": F = " << f << " N, Sneddon " << sneddon
                  << " N, error " << 100 * error << " %\n";
        EXPECT_LT(std::abs(error), previousError + 1e-9);
        previousError = std::abs(error);
    }
    EXPECT_LT(previousError, 0.10);
}

}  // namespace
}  // namespace palp::fem
