#include "solvers/pcg.h"

#include <tbb/blocked_range.h>
#include <tbb/parallel_reduce.h>

#include <cmath>

#include "palp/base/parallel.h"

namespace palp::fem {

namespace {

/// y = A x over row blocks on TBB workers (each row summed in storage order).
void parallelSpmv(const RowSparseMatrix& a, const Eigen::VectorXd& x, Eigen::VectorXd& y) {
    const int* outer = a.outerIndexPtr();
    const int* inner = a.innerIndexPtr();
    const double* val = a.valuePtr();
    parallelFor(tbb::blocked_range<int>(0, static_cast<int>(a.rows()), 1024),
                [&](const tbb::blocked_range<int>& r) {
                    for (int i = r.begin(); i != r.end(); ++i) {
                        double s = 0.0;
                        for (int p = outer[i]; p < outer[i + 1]; ++p) s += val[p] * x[inner[p]];
                        y[i] = s;
                    }
                });
}

double parallelDot(const Eigen::VectorXd& a, const Eigen::VectorXd& b) {
    return tbb::parallel_reduce(
        tbb::blocked_range<Eigen::Index>(0, a.size(), 4096), 0.0,
        [&](const tbb::blocked_range<Eigen::Index>& r, double s) {
            return s + a.segment(r.begin(), r.end() - r.begin())
                           .dot(b.segment(r.begin(), r.end() - r.begin()));
        },
        [](double x, double y) { return x + y; });
}

}  // namespace

int solveJacobiPcg(const RowSparseMatrix& a, const Eigen::VectorXd& inverseDiagonal,
                   const Eigen::VectorXd& b, Eigen::VectorXd& x, PcgWorkspace& work,
                   double relativeTolerance, int maxIterations) {
    const double bnorm = std::sqrt(parallelDot(b, b));
    if (bnorm == 0.0) {
        x.setZero();
        return 0;
    }
    work.q.resize(b.size());
    parallelSpmv(a, x, work.q);
    work.r = b - work.q;
    work.z = inverseDiagonal.cwiseProduct(work.r);
    work.p = work.z;
    double rz = parallelDot(work.r, work.z);
    const double tol = relativeTolerance * bnorm;
    int iterations = 0;
    while (std::sqrt(parallelDot(work.r, work.r)) > tol && iterations < maxIterations) {
        parallelSpmv(a, work.p, work.q);
        const double step = rz / parallelDot(work.p, work.q);
        x += step * work.p;
        work.r -= step * work.q;
        work.z = inverseDiagonal.cwiseProduct(work.r);
        const double rzNew = parallelDot(work.r, work.z);
        work.p = work.z + (rzNew / rz) * work.p;
        rz = rzNew;
        ++iterations;
    }
    return iterations;
}

}  // namespace palp::fem
