#pragma once
/// @file
/// The one Jacobi-preconditioned conjugate gradient of palp_fem (ImplicitSolver's pcg solver and
/// the asynchronous regions' PCG secondary): warm-started, with the SpMV and the dot products on
/// TBB workers (inside the caller's task_arena when it runs in one).

#include <Eigen/Core>
#include <Eigen/SparseCore>

namespace palp::fem {

/// Row-major sparse matrix: rows are independent in the parallel SpMV.
using RowSparseMatrix = Eigen::SparseMatrix<double, Eigen::RowMajor, int>;

/// Work vectors of solveJacobiPcg(): sized on first use, reused afterwards without allocation.
struct PcgWorkspace {
    Eigen::VectorXd r, z, p, q;
};

/// Solves `A x = b` for symmetric positive definite @p a by CG with the Jacobi preconditioner
/// @p inverseDiagonal (`1 / diag(A)`), starting from the value of @p x (warm start), until
/// `||r|| <= relativeTolerance * ||b||` or @p maxIterations iterations. For `b = 0` x is zero.
/// @return the iterations taken. Allocates only when @p work is not yet sized to b.
/// @par Threading  The SpMV (row blocks) and the dots (tbb::parallel_reduce) use TBB workers of
/// the calling thread's arena; one caller per @p work.
int solveJacobiPcg(const RowSparseMatrix& a, const Eigen::VectorXd& inverseDiagonal,
                   const Eigen::VectorXd& b, Eigen::VectorXd& x, PcgWorkspace& work,
                   double relativeTolerance, int maxIterations);

}  // namespace palp::fem
