// The period map of the plain (staggered) coupling and its spectral radius (async_stability.h).
#include "palp/fem/async_stability.h"

#include <Eigen/CholmodSupport>
#include <Eigen/Eigenvalues>
#include <algorithm>
#include <cmath>

#include "index_cast.h"
#include "palp/base/error.h"
#include "regions/async_layout.h"
#include "regions/async_setup.h"
#include "regions/layout_builder.h"

namespace palp::fem {

namespace {

using Triplet = Eigen::Triplet<double, int>;

/// Rows @p rows and columns @p cols of @p a.
SparseMatrix subMatrix(const SparseMatrix& a, const std::vector<int>& rows,
                       const std::vector<int>& cols) {
    std::vector<int> colPos(static_cast<std::size_t>(a.cols()), -1);
    for (std::size_t j = 0; j < cols.size(); ++j) colPos[sz(cols[j])] = static_cast<int>(j);
    std::vector<Triplet> t;
    for (std::size_t i = 0; i < rows.size(); ++i) {
        // SparseMatrix is column-major and symmetric: row r of a is column r.
        for (SparseMatrix::InnerIterator it(a, rows[i]); it; ++it) {
            const int j = colPos[sz(static_cast<int>(it.row()))];
            if (j >= 0) t.emplace_back(static_cast<int>(i), j, it.value());
        }
    }
    SparseMatrix b(static_cast<Eigen::Index>(rows.size()), static_cast<Eigen::Index>(cols.size()));
    b.setFromTriplets(t.begin(), t.end());
    return b;
}

/// The period map, applied to blocks of state columns.
class PeriodMap {
  public:
    PeriodMap(const AsyncSetup& setup, const Layout& L, const SparseMatrix& k) : mSetup(setup) {
        const FemModel& model = setup.model;
        const AsyncRegionsOptions& o = setup.options;
        const double critical = o.safetyFactor * model.criticalTimeStep();
        substeps = std::min(o.maxSubsteps,
                            std::max(1, static_cast<int>(std::ceil(o.tickSeconds / critical))));
        mDt = o.tickSeconds / substeps;
        mN = setup.period * substeps;
        nF = static_cast<Eigen::Index>(L.freeDofs.size());
        nG = static_cast<Eigen::Index>(L.gammaDofs.size());
        nU = static_cast<Eigen::Index>(L.unknownCoarseDof.size());
        mDynamic = o.secondaryIntegrator != Integrator::quasiStatic;
        mKff = subMatrix(k, L.freeDofs, L.freeDofs);
        mKfg = subMatrix(k, L.freeDofs, L.gammaDofs);
        // The border dofs the primary integrates (the others, driven or fixed, stay zero).
        std::vector<int> pos(sz(model.dofCount()), -1);
        for (std::size_t i = 0; i < L.freeDofs.size(); ++i)
            pos[sz(L.freeDofs[i])] = static_cast<int>(i);
        std::vector<Triplet> sel;
        for (std::size_t j = 0; j < L.borderDofs.size(); ++j)
            if (pos[sz(L.borderDofs[j])] >= 0)
                sel.emplace_back(static_cast<int>(j), pos[sz(L.borderDofs[j])], 1.0);
        mBorderOfFree.resize(static_cast<Eigen::Index>(L.borderDofs.size()), nF);
        mBorderOfFree.setFromTriplets(sel.begin(), sel.end());
        const Eigen::VectorXd& mass = model.lumpedMass();
        const double alpha = model.material().dampingAlpha;
        mBeta = model.material().dampingBeta;
        mInvDen.resize(nF);
        mPrevCoef.resize(nF);
        mTwoMass.resize(nF);
        for (Eigen::Index i = 0; i < nF; ++i) {
            const double m = mass[L.freeDofs[sz(static_cast<int>(i))]];
            mInvDen[i] = 1.0 / (m + 0.5 * mDt * alpha * m);
            mPrevCoef[i] = m - 0.5 * mDt * alpha * m;
            mTwoMass[i] = 2.0 * m;
        }
        mKcb = SparseMatrix(L.kcb);
        mInterpGamma = SparseMatrix(L.interpGamma);
        mKc = L.kc;
        mMc = L.mc;
        mSolver.compute(setup.sK * L.kc + setup.sM * L.mc);
        if (mSolver.info() != Eigen::Success)
            throw ValueError("staggeredStability: the secondary system is singular");
        if (!mDynamic) mR = mInterpGamma * mSolver.solve(Eigen::MatrixXd(-setup.sK * mKcb));
        mLead = !o.interpolate ? 0.0 : o.plainLead;  // < 0: interpolate (a period late)
        mX0 = 2 * nF + 2 * nG;
        stateSize = mX0 + (mDynamic ? 3 * nU : 0);
    }

    /// z <- Phi z for each column of @p z.
    void apply(Eigen::MatrixXd& z) const {
        const Eigen::Index c = z.cols();
        Eigen::MatrixXd u = z.middleRows(0, nF), up = z.middleRows(nF, nF);
        const Eigen::MatrixXd gp = z.middleRows(2 * nF, nG), gc = z.middleRows(2 * nF + nG, nG);
        const double dt2 = mDt * mDt;
        Eigen::MatrixXd f(nF, c), g(nG, c), operand(nF, c), next(nF, c);
        // Gamma at fraction @p frac of the period, as PrimaryRegion::setGamma shows it.
        auto gammaAt = [&](double frac) -> Eigen::MatrixXd {
            if (mLead >= 0.0) return gc + (mLead * frac) * (gc - gp);
            return gp + frac * (gc - gp);
        };
        for (int s = 0; s < mN; ++s) {
            g = gammaAt(static_cast<double>(s) / mN);
            if (mBeta > 0.0) {
                const Eigen::MatrixXd gPrev = gammaAt(static_cast<double>(std::max(0, s - 1)) / mN);
                operand = u + (mBeta / mDt) * (u - up);
                f = mKff * operand + mKfg * (g + (mBeta / mDt) * (g - gPrev));
            } else {
                f = mKff * u + mKfg * g;
            }
            next = (mInvDen.asDiagonal() *
                    (-dt2 * f + mTwoMass.asDiagonal() * u - mPrevCoef.asDiagonal() * up));
            up.swap(u);
            u.swap(next);
        }
        // The secondary solves the border read at the period's end; the primary accepts the
        // solution at fraction 1 (the previous one becomes gc).
        const Eigen::MatrixXd border = mBorderOfFree * u;
        Eigen::MatrixXd gNew;
        if (!mDynamic) {
            gNew = mR * border;
        } else {
            const NewmarkCoefficients& nm = mSetup.nm;
            const double alpha = mSetup.model.material().dampingAlpha;
            auto x = z.middleRows(mX0, nU);
            auto v = z.middleRows(mX0 + nU, nU);
            auto a = z.middleRows(mX0 + 2 * nU, nU);
            const Eigen::MatrixXd yc = nm.a1 * x + nm.a4 * v + nm.a5 * a;
            Eigen::MatrixXd rhs = -mSetup.sK * (mKcb * border);
            rhs += mMc * (nm.a0 * x + nm.a2 * v + nm.a3 * a + alpha * yc);
            if (mBeta > 0.0) rhs += mBeta * (mKc * yc);
            const Eigen::MatrixXd xNew = mSolver.solve(rhs);
            const double dt = mSetup.periodSeconds;
            if (mSetup.options.secondaryIntegrator == Integrator::newmark) {
                const Eigen::MatrixXd aNew = nm.a0 * (xNew - x) - nm.a2 * v - nm.a3 * a;
                v += dt * 0.5 * (a + aNew);
                a = aNew;
            } else {
                const Eigen::MatrixXd vNew = (xNew - x) / dt;
                a = (vNew - v) / dt;
                v = vNew;
            }
            x = xNew;
            gNew = mInterpGamma * xNew;
        }
        z.middleRows(0, nF) = u;
        z.middleRows(nF, nF) = up;
        z.middleRows(2 * nF, nG) = gc;
        z.middleRows(2 * nF + nG, nG) = gNew;
    }

    int substeps = 1;
    Eigen::Index nF = 0, nG = 0, nU = 0;
    Eigen::Index stateSize = 0;

  private:
    const AsyncSetup& mSetup;
    double mDt = 0.0, mBeta = 0.0;
    int mN = 1;
    bool mDynamic = false;
    SparseMatrix mKff, mKfg, mBorderOfFree, mKcb, mInterpGamma, mKc, mMc;
    Eigen::VectorXd mInvDen, mPrevCoef, mTwoMass;
    Eigen::CholmodSupernodalLLT<SparseMatrix, Eigen::Lower> mSolver;
    Eigen::MatrixXd mR;  // quasi-static: Gamma's response to the border
    double mLead = 0.0;
    Eigen::Index mX0 = 0;
};

/// Largest |eigenvalue| of @p h (square) and that eigenvalue.
std::complex<double> dominantEigenvalue(const Eigen::MatrixXd& h) {
    const Eigen::EigenSolver<Eigen::MatrixXd> es(h, false);
    std::complex<double> best = 0.0;
    for (Eigen::Index i = 0; i < h.rows(); ++i)
        if (std::abs(es.eigenvalues()[i]) > std::abs(best)) best = es.eigenvalues()[i];
    return best;
}

}  // namespace

StaggeredStability staggeredStability(const FemModel& model, const Constraints& constraints,
                                      const std::vector<int>& contactNodes,
                                      const AsyncRegionsOptions& options, int denseLimit,
                                      int arnoldiSteps, int powerPeriods) {
    AsyncRegionsOptions o = options;
    o.drive = ContactDrive::displacement;
    o.threaded = false;
    o.condensed = false;
    o.globalSecondary = false;  // the layout's own Galerkin system (no zone block)
    o.maxPrimaryNodes = 0;
    o.watchNodes.clear();
    const AsyncSetup setup(model, constraints, contactNodes, o);
    const LayoutBuilder builder(setup, contactNodes);
    const std::unique_ptr<Layout> L = builder.build(contactNodes, o.primaryNodes);
    const PeriodMap map(setup, *L, model.assembleStiffness());
    StaggeredStability out;
    out.stateSize = static_cast<int>(map.stateSize);
    out.periodTicks = setup.period;
    out.substeps = map.substeps;
    out.freeDofs = static_cast<int>(map.nF);
    out.gammaDofs = static_cast<int>(map.nG);
    out.borderDofs = static_cast<int>(L->borderDofs.size());
    const Eigen::Index n = map.stateSize;
    if (n == 0) return out;
    if (n <= denseLimit && o.secondaryIntegrator == Integrator::quasiStatic) {
        Eigen::MatrixXd phi = Eigen::MatrixXd::Identity(n, n);
        map.apply(phi);
        out.dominant = dominantEigenvalue(phi);
        out.dense = true;
    } else {
        // Arnoldi with full reorthogonalisation from a fixed start vector.
        const int m = static_cast<int>(std::min<Eigen::Index>(arnoldiSteps, n));
        Eigen::MatrixXd V = Eigen::MatrixXd::Zero(n, m + 1);
        Eigen::MatrixXd H = Eigen::MatrixXd::Zero(m + 1, m);
        V.col(0) = Eigen::VectorXd::LinSpaced(n, 1.0, 2.0);
        V.col(0).normalize();
        int steps = m;
        for (int j = 0; j < m; ++j) {
            Eigen::MatrixXd w = V.col(j);
            map.apply(w);
            for (int pass = 0; pass < 2; ++pass) {
                for (int i = 0; i <= j; ++i) {
                    const double hij = V.col(i).dot(w.col(0));
                    H(i, j) += hij;
                    w.col(0) -= hij * V.col(i);
                }
            }
            H(j + 1, j) = w.norm();
            if (H(j + 1, j) < 1e-12) {
                steps = j + 1;
                break;
            }
            V.col(j + 1) = w / H(j + 1, j);
        }
        out.dominant = dominantEigenvalue(H.topLeftCorner(steps, steps));
    }
    out.spectralRadius = std::abs(out.dominant);
    // Power iteration: the growth of a generic state over the last period.
    Eigen::MatrixXd z = Eigen::VectorXd::LinSpaced(n, -1.0, 1.0);
    z.normalize();
    double logSum = 0.0;
    int counted = 0;
    for (int k = 0; k < powerPeriods; ++k) {
        map.apply(z);
        const double norm = z.norm();
        if (!(norm > 0.0) || !std::isfinite(norm)) break;
        z /= norm;
        if (4 * k >= 3 * powerPeriods) {
            logSum += std::log(norm);
            ++counted;
        }
    }
    out.growthPerPeriod = counted > 0 ? std::exp(logSum / counted) : 0.0;
    return out;
}

}  // namespace palp::fem
