#include "palp/fem/implicit_solver.h"

#include <Eigen/CholmodSupport>
#include <Eigen/SparseCholesky>
#include <cmath>
#include <sstream>
#include <string>

#include "palp/base/error.h"
#include "palp/base/validate.h"
#include "solvers/pcg.h"

namespace palp::fem {

namespace {
constexpr double kNewmarkBeta = 0.25;
constexpr double kNewmarkGamma = 0.5;
}  // namespace

struct ImplicitSolver::Linear {
    SparseMatrix matrix;  // effective matrix on the free dofs
    Eigen::SimplicialLDLT<SparseMatrix, Eigen::Lower> ldlt;
    Eigen::CholmodSupernodalLLT<SparseMatrix, Eigen::Lower> cholmod;
    RowSparseMatrix rowMatrix;
    Eigen::VectorXd inverseDiagonal;
    PcgWorkspace pcg;
    bool analysed = false;
};

ImplicitSolver::ImplicitSolver(const FemModel& model, const Constraints& constraints,
                               const ImplicitOptions& options)
    : mModel(model), mOptions(options), mLinear(std::make_unique<Linear>()) {
    const int n = model.dofCount();
    if (constraints.dofCount() != n) {
        throwExpected("implicit solver constraints", std::to_string(n) + " dofs",
                      std::to_string(constraints.dofCount()));
    }
    if (model.material().law != MaterialLaw::linear) {
        throwExpected("implicit solver material law",
                      "linear (the neo-Hookean law runs in the explicit solver only)",
                      "neo-Hookean");
    }
    mK = model.assembleStiffness();
    const Eigen::VectorXd& mass = model.lumpedMass();
    std::vector<int> freeIndex(static_cast<std::size_t>(n), -1);
    for (int d = 0; d < n; ++d) {
        if (constraints.isFixed(d) || mass[d] <= 0.0) {
            mFixedDofs.push_back(d);
        } else {
            freeIndex[static_cast<std::size_t>(d)] = static_cast<int>(mFreeDofs.size());
            mFreeDofs.push_back(d);
        }
    }
    std::vector<int> fixedIndex(static_cast<std::size_t>(n), -1);
    for (std::size_t q = 0; q < mFixedDofs.size(); ++q) {
        fixedIndex[static_cast<std::size_t>(mFixedDofs[q])] = static_cast<int>(q);
    }
    const int nf = static_cast<int>(mFreeDofs.size());
    const int nc = static_cast<int>(mFixedDofs.size());
    if (nf == 0) {
        throw ValueError(
            "implicit solver: expected at least one free dof, found every dof "
            "constrained");
    }
    std::vector<Eigen::Triplet<double, int>> ff, fc;
    ff.reserve(static_cast<std::size_t>(mK.nonZeros()));
    for (int col = 0; col < n; ++col) {
        for (SparseMatrix::InnerIterator it(mK, col); it; ++it) {
            const int row = static_cast<int>(it.row());
            const int fr = freeIndex[static_cast<std::size_t>(row)];
            if (fr < 0) continue;
            const int fcol = freeIndex[static_cast<std::size_t>(col)];
            if (fcol >= 0) {
                ff.emplace_back(fr, fcol, it.value());
            } else {
                fc.emplace_back(fr, fixedIndex[static_cast<std::size_t>(col)], it.value());
            }
        }
    }
    mKff.resize(nf, nf);
    mKff.setFromTriplets(ff.begin(), ff.end());
    mKfc.resize(nf, nc);
    mKfc.setFromTriplets(fc.begin(), fc.end());
    mMassFree.resize(nf);
    for (int q = 0; q < nf; ++q) mMassFree[q] = mass[mFreeDofs[static_cast<std::size_t>(q)]];

    mU = Eigen::VectorXd::Zero(n);
    for (int d : mFixedDofs) mU[d] = constraints.isFixed(d) ? constraints.values()[d] : 0.0;
    mV = Eigen::VectorXd::Zero(n);
    mA = Eigen::VectorXd::Zero(n);
    mForce = Eigen::VectorXd::Zero(n);
    mReaction = Eigen::VectorXd::Zero(n);
    mTarget = mU;

    if (options.integrator == Integrator::quasiStatic) {
        // Supports must remove every rigid-body motion: check the pivots of K_ff once (an LDLT
        // of K_ff; with CHOLMOD the failed or near-singular Cholesky is the check instead).
        if (options.solver == LinearSolverKind::cholmod) {
            if (!prepare(1.0, 0.0)) {
                std::ostringstream s;
                s << "static problem supports: expected constraints that remove all rigid-body "
                     "motions, found a singular stiffness (CHOLMOD factorisation failed; "
                  << nc << " constrained dofs)";
                throw ValueError(s.str());
            }
            return;
        }
        Eigen::SimplicialLDLT<SparseMatrix, Eigen::Lower> check(mKff);
        const Eigen::VectorXd dvec = check.vectorD();
        const double maxD = dvec.cwiseAbs().maxCoeff();
        const double minD = dvec.minCoeff();
        if (check.info() != Eigen::Success || !(minD > 1e-10 * maxD)) {
            std::ostringstream s;
            s << "static problem supports: expected constraints that remove all rigid-body "
                 "motions, found a singular stiffness (smallest pivot "
              << minD << ", largest " << maxD << "; " << nc << " constrained dofs)";
            throw ValueError(s.str());
        }
        if (!prepare(1.0, 0.0)) {
            throw ValueError(
                "static problem: expected a positive definite stiffness, found a "
                "failed factorisation");
        }
    }
}

ImplicitSolver::~ImplicitSolver() = default;

bool ImplicitSolver::prepare(double stiffnessScale, double massScale) noexcept {
    if (stiffnessScale == mStiffnessScale && massScale == mMassScale) return true;
    try {
        Linear& lin = *mLinear;
        lin.matrix = stiffnessScale * mKff;
        for (int q = 0; q < lin.matrix.cols(); ++q)
            lin.matrix.coeffRef(q, q) += massScale * mMassFree[q];
        switch (mOptions.solver) {
            case LinearSolverKind::simplicialLdlt:
                if (!lin.analysed) lin.ldlt.analyzePattern(lin.matrix);
                lin.ldlt.factorize(lin.matrix);
                if (lin.ldlt.info() != Eigen::Success) return false;
                break;
            case LinearSolverKind::cholmod:
                if (!lin.analysed) lin.cholmod.analyzePattern(lin.matrix);
                lin.cholmod.factorize(lin.matrix);
                if (lin.cholmod.info() != Eigen::Success) return false;
                break;
            case LinearSolverKind::pcg:
                lin.rowMatrix = lin.matrix;
                lin.inverseDiagonal = lin.matrix.diagonal().cwiseInverse();
                break;
        }
        lin.analysed = true;
        ++mFactorisations;
        mStiffnessScale = stiffnessScale;
        mMassScale = massScale;
        return true;
    } catch (...) {
        return false;
    }
}

bool ImplicitSolver::solve(const Eigen::VectorXd& b, Eigen::VectorXd& x) noexcept {
    try {
        Linear& lin = *mLinear;
        mIterations = 0;
        switch (mOptions.solver) {
            case LinearSolverKind::simplicialLdlt:
                x = lin.ldlt.solve(b);
                break;
            case LinearSolverKind::cholmod:
                x = lin.cholmod.solve(b);
                break;
            case LinearSolverKind::pcg:
                // x holds the warm start (previous solution).
                mIterations =
                    solveJacobiPcg(lin.rowMatrix, lin.inverseDiagonal, b, x, lin.pcg,
                                   mOptions.pcgRelativeTolerance, mOptions.pcgMaxIterations);
                break;
        }
        return x.allFinite();
    } catch (...) {
        return false;
    }
}

StepResult ImplicitSolver::step(double dt) noexcept {
    StepResult result;
    if (!(dt > 0.0) || !std::isfinite(dt)) {
        result.flags |= kStepBadTimeStep;
        return result;
    }
    if (!mForce.allFinite()) {
        for (Eigen::Index d = 0; d < mForce.size(); ++d) {
            if (!std::isfinite(mForce[d])) mForce[d] = 0.0;
        }
        result.flags |= kStepBadForce;
    }
    try {
        const double alpha = mModel.material().dampingAlpha;
        const double betaR = mModel.material().dampingBeta;
        const Eigen::VectorXd& mass = mModel.lumpedMass();
        const bool dynamic = mOptions.integrator != Integrator::quasiStatic;
        if (dynamic && !mStarted) {
            // Initial acceleration from equilibrium: M a0 = f - K u0 - C v0 (lumped M).
            const Eigen::VectorXd ku = mK * (mU + betaR * mV);
            for (int d : mFreeDofs) mA[d] = (mForce[d] - ku[d]) / mass[d] - alpha * mV[d];
        }
        mStarted = true;
        // Effective system (K + a0 M + a1 C) with C = alpha M + betaR K.
        double a0 = 0, a1 = 0, a2 = 0, a3 = 0, a4 = 0, a5 = 0;
        if (mOptions.integrator == Integrator::newmark) {
            a0 = 1.0 / (kNewmarkBeta * dt * dt);
            a1 = kNewmarkGamma / (kNewmarkBeta * dt);
            a2 = 1.0 / (kNewmarkBeta * dt);
            a3 = 1.0 / (2.0 * kNewmarkBeta) - 1.0;
            a4 = kNewmarkGamma / kNewmarkBeta - 1.0;
            a5 = dt * (kNewmarkGamma / (2.0 * kNewmarkBeta) - 1.0);
        } else if (mOptions.integrator == Integrator::backwardEuler) {
            a0 = 1.0 / (dt * dt);
            a1 = 1.0 / dt;
            a2 = 1.0 / dt;
        }
        const double sK = 1.0 + a1 * betaR;
        const double sM = a0 + a1 * alpha;
        if (!prepare(sK, sM)) {
            result.flags |= kStepDiverged;
            return result;
        }
        Eigen::VectorXd rhs = mForce;
        if (dynamic) {
            const Eigen::VectorXd yc = a1 * mU + a4 * mV + a5 * mA;
            const Eigen::VectorXd ym = a0 * mU + a2 * mV + a3 * mA + alpha * yc;
            rhs += mass.cwiseProduct(ym);
            if (betaR > 0.0) rhs += betaR * (mK * yc);
        }
        const int nf = static_cast<int>(mFreeDofs.size());
        Eigen::VectorXd b(nf), x(nf), uc(static_cast<Eigen::Index>(mFixedDofs.size()));
        for (std::size_t q = 0; q < mFixedDofs.size(); ++q) {
            uc[static_cast<Eigen::Index>(q)] = mTarget[mFixedDofs[q]];
        }
        for (int q = 0; q < nf; ++q) {
            b[q] = rhs[mFreeDofs[static_cast<std::size_t>(q)]];
            x[q] = mU[mFreeDofs[static_cast<std::size_t>(q)]];  // warm start for PCG
        }
        if (uc.size() > 0) b -= sK * (mKfc * uc);
        if (!solve(b, x)) {
            result.flags |= kStepDiverged;
            return result;
        }
        const Eigen::VectorXd uOld = mU;
        for (int q = 0; q < nf; ++q) mU[mFreeDofs[static_cast<std::size_t>(q)]] = x[q];
        for (int d : mFixedDofs) mU[d] = mTarget[d];
        if (mOptions.integrator == Integrator::newmark) {
            const Eigen::VectorXd aNew = a0 * (mU - uOld) - a2 * mV - a3 * mA;
            mV += dt * ((1.0 - kNewmarkGamma) * mA + kNewmarkGamma * aNew);
            mA = aNew;
        } else if (mOptions.integrator == Integrator::backwardEuler) {
            const Eigen::VectorXd vNew = (mU - uOld) / dt;
            mA = (vNew - mV) / dt;
            mV = vNew;
        }
        mReaction = mK * (mU + betaR * mV) + mass.cwiseProduct(mA + alpha * mV) - mForce;
        mTime += dt;
        result.substeps = 1;
        result.advancedSeconds = dt;
    } catch (...) {
        result.flags |= kStepDiverged;
    }
    return result;
}

Eigen::Vector3d ImplicitSolver::reactionSum(const std::vector<int>& nodes) const {
    Eigen::Vector3d r = Eigen::Vector3d::Zero();
    for (int n : nodes) {
        for (int c = 0; c < 3; ++c) r[c] += mReaction[3 * n + c];
    }
    return r;
}

double ImplicitSolver::kineticEnergy() const {
    return 0.5 * mV.dot(mModel.lumpedMass().cwiseProduct(mV));
}

double ImplicitSolver::strainEnergy() const { return 0.5 * mU.dot(mK * mU); }

}  // namespace palp::fem
