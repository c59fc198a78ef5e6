#include <gtest/gtest.h>

#include <Eigen/Eigenvalues>
#include <random>

#include "fem_test_util.h"
#include "palp/fem/fem_model.h"
#include "palp/fem/hex_element.h"
#include "palp/fem/implicit_solver.h"

namespace palp::fem {
namespace {

/// Random inhomogeneous body with voids: 6x5x4 cells, E in [1, 9] kPa, a few void cells.
HexMesh randomBody(unsigned seed) {
    std::mt19937 rng(seed);
    std::uniform_real_distribution<double> e(1e3, 9e3);
    std::vector<double> cells(6 * 5 * 4);
    for (auto& v : cells) v = e(rng);
    cells[7] = 0.0;
    cells[33] = 0.0;
    return HexMesh::fromCells({7, 6, 5}, 0.004, Eigen::Vector3d(0.01, -0.02, 0.0), cells);
}

TEST(HexElement, StiffnessHasSixRigidModesAndIsPositiveOtherwise) {
    const Eigen::Matrix<double, 24, 24> k = hexStiffness(0.005, 5e3, 0.45);
    EXPECT_LT((k - k.transpose()).norm(), 1e-14 * k.norm());
    const Eigen::SelfAdjointEigenSolver<Eigen::Matrix<double, 24, 24>> eig(k);
    const auto& ev = eig.eigenvalues();
    for (int i = 0; i < 6; ++i) EXPECT_LT(std::abs(ev[i]), 1e-12 * ev[23]);
    EXPECT_GT(ev[6], 1e-3 * ev[23]);
    // Uniform strain eps_zz = 1 on a unit-E cube of edge h: strain energy = C33 / 2 * h^3.
    Eigen::Matrix<double, 24, 1> u;
    for (int a = 0; a < 8; ++a) {
        u.segment<3>(3 * a) = Eigen::Vector3d(0, 0, (a & 4) ? 0.005 : 0.0);
    }
    const double c33 = elasticityMatrix(5e3, 0.45)(2, 2);
    EXPECT_NEAR(0.5 * u.dot(k * u), 0.5 * c33 * std::pow(0.005, 3), 1e-12 * c33 * 1e-7);
}

TEST(FemModel, AssembledMatchesMatrixFreeAndParallel) {
    const FemModel model(randomBody(3), test::softTissue());
    const SparseMatrix k = model.assembleStiffness();
    EXPECT_LT((k - SparseMatrix(k.transpose())).norm(), 1e-12 * k.norm());
    std::mt19937 rng(5);
    std::normal_distribution<double> g;
    Eigen::VectorXd u(model.dofCount());
    for (auto& v : u) v = 1e-3 * g(rng);
    Eigen::VectorXd f1 = Eigen::VectorXd::Zero(u.size());
    model.addStiffnessTimes(u.data(), f1.data());
    const Eigen::VectorXd f2 = k * u;
    EXPECT_LT((f1 - f2).norm(), 1e-12 * f2.norm());
    Eigen::VectorXd f3(u.size());
    model.stiffnessTimesParallel(u.data(), f3.data());
    EXPECT_LT((f1 - f3).norm(), 1e-13 * f1.norm());
}

TEST(FemModel, MatrixFreeMatchesAssembledForEveryRowWidth) {
    // The kernel takes the cells of an x-row in batches (3 or 4 by instruction set) and the rest
    // one by one, and skips batches of void cells: rows of 1 to 9 cells cover full batches,
    // tails, batches with a void cell and batches that are all void.
    std::mt19937 rng(17);
    std::uniform_real_distribution<double> e(1e3, 9e3);
    for (int cx = 1; cx <= 9; ++cx) {
        std::vector<double> cells(static_cast<std::size_t>(cx) * 3 * 2);
        for (auto& v : cells) v = e(rng);
        for (std::size_t c = 0; c < cells.size(); c += 5) cells[c] = 0.0;
        for (int i = 0; i < std::min(cx, 4); ++i) cells[static_cast<std::size_t>(cx + i)] = 0.0;
        const FemModel model(
            HexMesh::fromCells({cx + 1, 4, 3}, 0.003, Eigen::Vector3d::Zero(), cells),
            test::softTissue());
        const SparseMatrix k = model.assembleStiffness();
        Eigen::VectorXd u(model.dofCount());
        std::normal_distribution<double> g;
        for (auto& v : u) v = 1e-3 * g(rng);
        Eigen::VectorXd f = Eigen::VectorXd::Zero(u.size());
        model.addStiffnessTimes(u.data(), f.data());
        const Eigen::VectorXd ref = k * u;
        EXPECT_LT((f - ref).norm(), 1e-12 * ref.norm()) << cx << " cells a row";
    }
}

TEST(FemModel, RigidBodyMotionsGiveZeroInternalForce) {
    const FemModel model(randomBody(11), test::softTissue());
    const HexMesh& mesh = model.mesh();
    const Eigen::Matrix3d rot =
        Eigen::AngleAxisd(1e-3, Eigen::Vector3d(1, 2, 3).normalized()).toRotationMatrix() -
        Eigen::Matrix3d::Identity();  // infinitesimal rotation part (skew to first order)
    const Eigen::Matrix3d skew = 0.5 * (rot - rot.transpose());
    Eigen::VectorXd translation(model.dofCount()), rotation(model.dofCount()),
        stretch(model.dofCount());
    for (int n = 0; n < mesh.nodeCount(); ++n) {
        const Eigen::Vector3d x = mesh.nodePosition(n);
        translation.segment<3>(3 * n) = Eigen::Vector3d(1e-3, -2e-3, 5e-4);
        rotation.segment<3>(3 * n) = skew * x;
        stretch.segment<3>(3 * n) = Eigen::Vector3d(1e-3 * x.x(), 0, 0);
    }
    auto forceNorm = [&](const Eigen::VectorXd& u) {
        Eigen::VectorXd f = Eigen::VectorXd::Zero(u.size());
        model.addStiffnessTimes(u.data(), f.data());
        return f.norm();
    };
    const double scale = forceNorm(stretch);  // a deformation of similar magnitude
    EXPECT_GT(scale, 0.0);
    EXPECT_LT(forceNorm(translation), 1e-12 * scale * 2.0);
    EXPECT_LT(forceNorm(rotation), 1e-10 * scale);
}

TEST(FemModel, PatchTestReproducesLinearFieldsInTheInterior) {
    // Boundary nodes follow u = A x + b; the static solution must be that field everywhere,
    // with zero residual force at every interior node.
    const HexMesh mesh = HexMesh::box(Eigen::Vector3d(0.03, 0.025, 0.02), {7, 6, 5}, 5e3);
    const FemModel model(mesh, test::softTissue());
    Eigen::Matrix3d a;
    a << 1e-2, 3e-3, -2e-3, 4e-3, -5e-3, 1e-3, -3e-3, 2e-3, 7e-3;
    const Eigen::Vector3d b(1e-4, -2e-4, 3e-4);
    Constraints c(mesh.dofCount());
    Eigen::VectorXd exact(mesh.dofCount());
    for (int n = 0; n < mesh.nodeCount(); ++n) {
        const Eigen::Vector3d x = mesh.nodePosition(n);
        exact.segment<3>(3 * n) = a * x + b;
        const auto ijk = mesh.nodeCoords(n);
        const bool boundary =
            ijk[0] == 0 || ijk[1] == 0 || ijk[2] == 0 || ijk[0] == 6 || ijk[1] == 5 || ijk[2] == 4;
        if (boundary) {
            for (int d = 0; d < 3; ++d) c.prescribe(3 * n + d, exact[3 * n + d]);
        }
    }
    ImplicitSolver solver(model, c, {Integrator::quasiStatic, LinearSolverKind::simplicialLdlt});
    const StepResult r = solver.step(1.0);
    EXPECT_EQ(r.flags, kStepOk);
    EXPECT_LT((solver.displacement() - exact).cwiseAbs().maxCoeff(), 1e-12);
    Eigen::VectorXd f = Eigen::VectorXd::Zero(mesh.dofCount());
    model.addStiffnessTimes(exact.data(), f.data());
    double interiorMax = 0.0, boundaryMax = 0.0;
    for (int d = 0; d < mesh.dofCount(); ++d) {
        (c.isFixed(d) ? boundaryMax : interiorMax) =
            std::max(c.isFixed(d) ? boundaryMax : interiorMax, std::abs(f[d]));
    }
    EXPECT_GT(boundaryMax, 0.0);
    EXPECT_LT(interiorMax, 1e-12 * boundaryMax);
}

TEST(FemModel, LumpedMassAndStableStep) {
    const FemModel model(test::cube13(), test::softTissue());
    EXPECT_NEAR(model.totalMass(), 1e3 * std::pow(0.06, 3), 1e-12);
    // Element bound: dt = kappa h / c_d with kappa about 0.62 at nu = 0.45 (docs/algorithms.md 5).
    const double kappa =
        model.criticalTimeStep() * model.material().dilatationalWaveSpeed() / model.mesh().edge();
    EXPECT_NEAR(kappa, 0.62, 0.03);
    // Stiffer elements shrink the step as 1 / sqrt(E).
    const FemModel stiff(test::cube13(2e4), test::softTissue());
    EXPECT_NEAR(stiff.criticalTimeStep() / model.criticalTimeStep(), 0.5, 1e-12);
}

}  // namespace
}  // namespace palp::fem
