// The shared Jacobi-preconditioned CG (fem/src/solvers/pcg.h): agreement with a direct solve, the
// warm start, a zero right-hand side and the iteration bound.
#include <gtest/gtest.h>

#include <Eigen/SparseCholesky>
#include <cmath>
#include <vector>

#include "solvers/pcg.h"

namespace palp::fem {
namespace {

/// 1-D Laplacian with a varying diagonal shift: symmetric positive definite, n x n.
RowSparseMatrix laplacian(int n) {
    std::vector<Eigen::Triplet<double, int>> t;
    for (int i = 0; i < n; ++i) {
        t.emplace_back(i, i, 2.0 + 0.01 * (i % 7));
        if (i > 0) t.emplace_back(i, i - 1, -1.0);
        if (i + 1 < n) t.emplace_back(i, i + 1, -1.0);
    }
    RowSparseMatrix a(n, n);
    a.setFromTriplets(t.begin(), t.end());
    return a;
}

TEST(Pcg, MatchesDirectSolve) {
    const int n = 5000;
    const RowSparseMatrix a = laplacian(n);
    const Eigen::VectorXd inv = Eigen::VectorXd(a.diagonal()).cwiseInverse();
    Eigen::VectorXd b(n);
    for (int i = 0; i < n; ++i) b[i] = std::sin(0.01 * i) + 0.5;
    const Eigen::SparseMatrix<double> ac = a;
    const Eigen::SimplicialLDLT<Eigen::SparseMatrix<double>> ldlt(ac);
    const Eigen::VectorXd exact = ldlt.solve(b);
    Eigen::VectorXd x = Eigen::VectorXd::Zero(n);
    PcgWorkspace work;
    const int iterations = solveJacobiPcg(a, inv, b, x, work, 1e-12, 20000);
    EXPECT_GT(iterations, 0);
    EXPECT_LT((a * x - b).norm(), 1e-11 * b.norm());
    EXPECT_LT((x - exact).norm(), 1e-8 * exact.norm());
    // Warm-started from the solution: no iteration needed.
    EXPECT_EQ(solveJacobiPcg(a, inv, b, x, work, 1e-10, 20000), 0);
}

TEST(Pcg, ZeroRightHandSideGivesZero) {
    const RowSparseMatrix a = laplacian(50);
    const Eigen::VectorXd inv = Eigen::VectorXd(a.diagonal()).cwiseInverse();
    Eigen::VectorXd x = Eigen::VectorXd::Ones(50);
    PcgWorkspace work;
    EXPECT_EQ(solveJacobiPcg(a, inv, Eigen::VectorXd::Zero(50), x, work, 1e-10, 100), 0);
    EXPECT_EQ(x.norm(), 0.0);
}

TEST(Pcg, StopsAtTheIterationBound) {
    const int n = 2000;
    const RowSparseMatrix a = laplacian(n);
    const Eigen::VectorXd inv = Eigen::VectorXd(a.diagonal()).cwiseInverse();
    const Eigen::VectorXd b = Eigen::VectorXd::Ones(n);
    Eigen::VectorXd x = Eigen::VectorXd::Zero(n);
    PcgWorkspace work;
    EXPECT_EQ(solveJacobiPcg(a, inv, b, x, work, 1e-14, 3), 3);
    EXPECT_TRUE(x.allFinite());
}

}  // namespace
}  // namespace palp::fem
