#include "regions/primary_region.h"

#include <Eigen/LU>
#include <algorithm>
#include <cmath>
#include <limits>

#include "index_cast.h"

namespace palp::fem {

namespace {
/// Whether @p L's condensed G is factored (gammaBasis capQ) and usable (its work vectors
/// fit: @p workRows values).
bool factoredGamma(const Layout& L, bool condensed, Eigen::Index workRows) noexcept {
    const std::size_t n = L.gammaDofs.size();
    return condensed && L.gammaBasis.fits(static_cast<Eigen::Index>(n), L.capQ.rows()) && n > 0 &&
           L.capQ.cols() == static_cast<Eigen::Index>(L.borderDofs.size()) &&
           2 * L.gammaBasis.block.rows() <= workRows;
}
}  // namespace

PrimaryRegion::PrimaryRegion(const AsyncSetup& setup, const Constraints& c,
                             const std::vector<int>& contact)
    : mSetup(setup) {
    const FemModel& model = setup.model;
    const AsyncRegionsOptions& o = setup.options;
    const int dofs = model.dofCount();
    const int nodes = model.mesh().nodeCount();
    // Central-difference coefficients (the same for every layout).
    // TLED: the undeformed one-point element's bound (its hourglass springs included); the
    // current state's shortens the substep in advance().
    const double critical =
        o.safetyFactor * (setup.tled
                              ? setup.tled->criticalTimeStep(setup.tled->restFrequencyBound())
                              : model.criticalTimeStep());
    mSubsteps =
        std::min(o.maxSubsteps, std::max(1, static_cast<int>(std::ceil(o.tickSeconds / critical))));
    mDtSub = o.tickSeconds / mSubsteps;
    mBaseSubsteps = mSubsteps;
    mBaseDt = mDtSub;
    mU = Eigen::VectorXd::Zero(dofs);
    for (int d = 0; d < dofs; ++d) {
        if (c.isFixed(d)) mU[d] = c.values()[d];
    }
    for (int n : contact) {
        for (int k = 0; k < 3; ++k) mU[3 * n + k] = 0.0;
    }
    mUPrev = mU;
    mFInt = Eigen::VectorXd::Zero(dofs);
    mWork = mU;
    mInvDen = Eigen::VectorXd::Zero(dofs);
    mPrevCoef = Eigen::VectorXd::Zero(dofs);
    mTwoMass = Eigen::VectorXd::Zero(dofs);
    const Eigen::VectorXd& mass = model.lumpedMass();
    const double alpha = model.material().dampingAlpha;
    for (int d = 0; d < dofs; ++d) {
        if (setup.fixed[sz(d)] || mass[d] <= 0.0) continue;
        mInvDen[d] = 1.0 / (mass[d] + 0.5 * mDtSub * alpha * mass[d]);
        mPrevCoef[d] = mass[d] - 0.5 * mDtSub * alpha * mass[d];
        mTwoMass[d] = 2.0 * mass[d];
    }
    mContactStart = Eigen::VectorXd::Zero(dofs);
    buildStencil();
    mGPrev.assign(sz(dofs), 0.0);
    mGCur = mGPrev;
    mBPrev = Eigen::VectorXd::Zero(dofs);
    mBCur = mBPrev;
    mBNow = mBPrev;
    mGFix = mBPrev;
    mEntryWork = mBPrev;
    mCapZ = Eigen::VectorXd::Zero(2 * std::max(1, setup.coarseDofs));
    mCapY = mCapZ;
    (void)sweepAvx2();  // its static, initialised here rather than on the servo
    mWPrev.assign(3 * o.watchNodes.size(), 0.0);
    mWCur = mWPrev;
    mFExt = Eigen::VectorXd::Zero(dofs);
    mFAcc = mFExt;
    mFExtDofs.assign(3 * sz(o.maxLoads), 0);
    mAccNodes.assign(sz(nodes), 0);
    mAccMark.assign(sz(nodes), 0);
    for (std::size_t a = 0; a < 3; ++a) {
        mSharePos[a].assign(kShareEntries, 0);
        mShareWeight[a].assign(kShareEntries, 0.0);
    }
    mShareV = Eigen::MatrixXd::Zero(std::max(1, setup.coarseDofs), 3);
    mShareHDV = mShareV;
    mShareH = Eigen::VectorXd::Zero(mShareV.rows());
    mShareSlot.assign(sz(std::max(1, setup.coarseDofs)), -1);
    mShareSeq.fill(~std::uint64_t{0});
    for (Eigen::Vector3d& f : mShareSent) f.setZero();
}

void PrimaryRegion::restartCoupling(const Layout& L) noexcept {
    // Gamma and the border start from the values the primary shows now.
    for (std::size_t i = 0; i < L.gammaDofs.size(); ++i) {
        mGPrev[i] = mU[L.gammaDofs[i]];
        mGCur[i] = mGPrev[i];
    }
    for (std::size_t i = 0; i < L.borderDofs.size(); ++i) {
        const Eigen::Index k = static_cast<Eigen::Index>(i);
        mBPrev[k] = mU[L.borderDofs[i]];
        mBCur[k] = mBPrev[k];
    }
    mGammaStart = mTime;
}

void PrimaryRegion::restartGammaFrom(const Layout& L, const Eigen::VectorXd& x) noexcept {
    const Eigen::Index ng = static_cast<Eigen::Index>(L.gammaDofs.size());
    Eigen::Map<Eigen::VectorXd> g(mGPrev.data(), ng);
    if (!L.unknownCoarseDof.empty()) {
        g.noalias() = L.interpGamma * x;
    } else {
        g.setZero();
    }
    std::copy(mGPrev.begin(), mGPrev.begin() + ng, mGCur.begin());
}

void PrimaryRegion::setGamma(const Layout& L, double* target, double t, bool product) noexcept {
    const double frac = mSetup.periodFraction(t, mGammaStart);
    const std::size_t n = L.gammaDofs.size();
    const bool factored = factoredGamma(L, mSetup.options.condensed, mCapY.size());
    if (factored || L.response.nonZeros() > 0) {
        const std::size_t nb = L.borderDofs.size();
        if (product) {
            bool moved = false;
            for (std::size_t i = 0; i < nb; ++i) {
                const Eigen::Index k = static_cast<Eigen::Index>(i);
                mBNow[k] = target[L.borderDofs[i]] - (mBPrev[k] + frac * (mBCur[k] - mBPrev[k]));
                moved = moved || mBNow[k] != 0.0;
            }
            const auto b = mBNow.head(static_cast<Eigen::Index>(nb));
            auto fix = mGFix.head(static_cast<Eigen::Index>(n));
            if (!moved) {
                // The border as the values shown answer it (the first substep after a swap,
                // restartCoupling()): G 0 = 0 without sweeping G.
                fix.setZero();
            } else if (factored) {
                // G b = gammaBasis (Q b): |J| (Q's rows) values in between.
                auto z = mCapZ.head(L.capQ.rows());
                z.noalias() = L.capQ * b;
                L.gammaBasis.apply(z, mCapY.head(L.gammaBasis.block.rows()), fix.data());
            } else {
                fix.noalias() = L.response * b;
            }
        }
        for (std::size_t i = 0; i < n; ++i)
            target[L.gammaDofs[i]] =
                mGPrev[i] + frac * (mGCur[i] - mGPrev[i]) + mGFix[static_cast<Eigen::Index>(i)];
        return;
    }
    if (leads()) {
        // Plain coupling: from the newest solution on along its last change (plainLead).
        const double lead = mSetup.options.plainLead * frac;
        for (std::size_t i = 0; i < n; ++i)
            target[L.gammaDofs[i]] = mGCur[i] + lead * (mGCur[i] - mGPrev[i]);
        return;
    }
    for (std::size_t i = 0; i < n; ++i)
        target[L.gammaDofs[i]] = mGPrev[i] + frac * (mGCur[i] - mGPrev[i]);
}

void PrimaryRegion::acceptSolution(const Layout& L, const double* gamma, const double* border,
                                   const double* watch, std::uint64_t sequence) noexcept {
    // Start from the value shown now, so a solution arriving mid-period does not jump.
    const double frac = mSetup.periodFraction(mTime, mGammaStart);
    mSharePrev += frac * (mShareCur - mSharePrev);
    for (std::size_t j = 0; j < mShareSeq.size(); ++j)
        if (mShareSeq[j] == sequence) mShareCur = mShareSent[j];
    // Plain coupling with a lead: the previous solution, which the lead extrapolates from.
    const bool lead = leads();
    for (std::size_t i = 0; i < L.gammaDofs.size(); ++i) {
        mGPrev[i] = lead ? mGCur[i] : mGPrev[i] + frac * (mGCur[i] - mGPrev[i]);
        mGCur[i] = gamma[i];
    }
    for (std::size_t i = 0; i < L.borderDofs.size(); ++i) {
        const Eigen::Index k = static_cast<Eigen::Index>(i);
        mBPrev[k] = mBPrev[k] + frac * (mBCur[k] - mBPrev[k]);
        mBCur[k] = border[i];
    }
    if (watch != nullptr) {
        const double g = watchedFraction(frac);
        if (g >= 1.0) {
            // The usual case (a solution taken at or after its period's end): the value shown
            // is the current one, so the buffers trade places and only the new one is copied
            // (the whole skin's watched values: 2 streams instead of 5 on a 2.5 mm head CT).
            std::swap(mWPrev, mWCur);
            std::copy(watch, watch + mWCur.size(), mWCur.begin());
        } else {
            for (std::size_t i = 0; i < mWPrev.size(); ++i) {
                mWPrev[i] = mWPrev[i] + g * (mWCur[i] - mWPrev[i]);
                mWCur[i] = watch[i];
            }
        }
        mWBase = 0.0;
    }
    mGammaStart = mTime;
    ++mUsed;
}

void PrimaryRegion::showBorder(const Layout& from) noexcept {
    // The border as the primary shows it now (current and previous substep); a factored G
    // takes both products in one sweep over each factor.
    if (factoredGamma(from, mSetup.options.condensed, mCapY.size())) {
        const Eigen::Index n = static_cast<Eigen::Index>(from.gammaDofs.size());
        const Eigen::Index nb = static_cast<Eigen::Index>(from.borderDofs.size());
        const Eigen::Index nj = from.capQ.rows();
        const double f = shownFraction();
        const double fPrev = mSetup.periodFraction(mTime - mDtSub, mGammaStart);
        for (Eigen::Index i = 0; i < nb; ++i) {
            const int d = from.borderDofs[sz(static_cast<int>(i))];
            mBNow[i] = mU[d] - (mBPrev[i] + f * (mBCur[i] - mBPrev[i]));
            mEntryWork[i] = mUPrev[d] - (mBPrev[i] + fPrev * (mBCur[i] - mBPrev[i]));
        }
        dualProduct(from.capQ, mBNow.head(nb), mEntryWork.head(nb), mCapZ.head(nj),
                    mCapZ.segment(nj, nj));
        dualProduct(from.gammaBasis, mCapZ.head(nj), mCapZ.segment(nj, nj), mCapY, mWork.data(),
                    mGFix.data());
        for (Eigen::Index i = 0; i < n; ++i) {
            const std::size_t k = sz(static_cast<int>(i));
            const int d = from.gammaDofs[k];
            mU[d] = mGPrev[k] + f * (mGCur[k] - mGPrev[k]) + mWork[i];
            mUPrev[d] = mGPrev[k] + fPrev * (mGCur[k] - mGPrev[k]) + mGFix[i];
        }
    } else {
        setGamma(from, mU.data(), mTime, true);
        setGamma(from, mUPrev.data(), mTime - mDtSub, true);
    }
    seedWatched(from);
}

void PrimaryRegion::adopt(const Layout& from, const Layout& to) noexcept {
    // Nodes the servo did not integrate or show take the prepared secondary values; the
    // coupling restarts from the shown values, so nothing jumps at the swap.
    showBorder(from);
    // The spring share the shown secondary values answer, as the watched values restart.
    mSharePrev += shownFraction() * (mShareCur - mSharePrev);
    const std::size_t nb = from.borderDofs.size();
    const Eigen::Index ne = static_cast<Eigen::Index>(to.entryDofs.size());
    const bool known = to.entryBorder.size() == static_cast<Eigen::Index>(nb) && ne > 0;
    const bool factored = known && to.entryBasis.fits(ne, to.entryQ.rows()) &&
                          to.entryQ.cols() == static_cast<Eigen::Index>(nb) &&
                          to.entryQ.rows() <= mCapZ.size() / 2 &&
                          2 * to.entryBasis.block.rows() <= mCapY.size();
    const bool respond = known && to.entryResponse.rows() == ne &&
                         to.entryResponse.cols() == static_cast<Eigen::Index>(nb);
    if (factored) {
        enterFactored(from, to);
    } else if (!respond) {
        for (std::size_t i = 0; i < to.entryDofs.size(); ++i)
            enter(to.entryDofs[i], to.entryValues[i]);
    } else {
        // The quasi-static values at the border shown now and at the previous substep, so the
        // entering nodes join the motion of their neighbours (position and velocity) instead
        // of a period-old rest state. (mBNow, mWork: work vectors, sized to the dofs.)
        const Eigen::Index n = static_cast<Eigen::Index>(nb);
        for (std::size_t i = 0; i < nb; ++i)
            mBNow[static_cast<Eigen::Index>(i)] =
                mU[from.borderDofs[i]] - to.entryBorder[static_cast<Eigen::Index>(i)];
        mWork.head(ne).noalias() = to.entryResponse * mBNow.head(n);
        for (std::size_t i = 0; i < nb; ++i)
            mBNow[static_cast<Eigen::Index>(i)] =
                mUPrev[from.borderDofs[i]] - to.entryBorder[static_cast<Eigen::Index>(i)];
        for (std::size_t i = 0; i < to.entryDofs.size(); ++i) {
            const Eigen::Index k = static_cast<Eigen::Index>(i);
            const int d = to.entryDofs[i];
            mU[d] = to.entryValues[i] + mWork[k];
            mUPrev[d] = to.entryValues[i] + to.entryResponse.row(k).dot(mBNow.head(n));
        }
    }
    applyShareCorrection(from, to);
    restartCoupling(to);
}

void PrimaryRegion::enterFactored(const Layout& from, const Layout& to) noexcept {
    // E = entryBasis entryQ: the border's motion since the prepared values through Q (|J|
    // values each for the position and the previous substep), then the basis, each factor
    // swept once for both (mWork and mEntryWork: work vectors).
    const std::size_t nb = from.borderDofs.size();
    const Eigen::Index nj = to.entryQ.rows();
    const Eigen::Index ne = static_cast<Eigen::Index>(to.entryDofs.size());
    const Eigen::Index n = static_cast<Eigen::Index>(nb);
    for (std::size_t i = 0; i < nb; ++i) {
        const Eigen::Index k = static_cast<Eigen::Index>(i);
        mBNow[k] = mU[from.borderDofs[i]] - to.entryBorder[k];
        mEntryWork[k] = mUPrev[from.borderDofs[i]] - to.entryBorder[k];
    }
    dualProduct(to.entryQ, mBNow.head(n), mEntryWork.head(n), mCapZ.head(nj),
                mCapZ.segment(nj, nj));
    auto w = mWork.head(ne);
    auto wPrev = mEntryWork.head(ne);
    dualProduct(to.entryBasis, mCapZ.head(nj), mCapZ.segment(nj, nj), mCapY, w.data(),
                wPrev.data());
    for (Eigen::Index i = 0; i < ne; ++i) {
        const int d = to.entryDofs[sz(static_cast<int>(i))];
        mU[d] = to.entryValues[sz(static_cast<int>(i))] + w[i];
        mUPrev[d] = to.entryValues[sz(static_cast<int>(i))] + wPrev[i];
    }
}

void PrimaryRegion::seedWatched(const Layout& from) noexcept {
    // Called before restartCoupling() restarts the interpolation clock. Watched nodes the servo
    // showed (P and Gamma of the layout being left) start from those values: the secondary's
    // last solution has nothing (zero) for primary nodes. The others restart their
    // interpolation from the value shown now towards the same newest solution: shown = S0 +
    // f' (cur - S0) with S0 = prev + g0 (cur - prev) is prev + (g0 + f' (1 - g0)) (cur - prev),
    // so keeping g0 in mWBase (watchedFraction()) restarts them without touching their values:
    // O(|P| + |Gamma|) at the swap instead of a pass over the whole skin's watched values (0.2-0.3
    // ms on the 2.5 mm head CT).
    mWBase = watchedFraction(shownFraction());
    const auto own = [&](const std::vector<int>& nodes) {
        for (const int n : nodes) {
            const int w = mSetup.watchIndex[sz(n)];
            if (w < 0) continue;
            for (std::size_t k = 0; k < 3; ++k) {
                const std::size_t j = 3 * sz(w) + k;
                mWPrev[j] = mU[3 * n + static_cast<int>(k)];
                mWCur[j] = mWPrev[j];
            }
        }
    };
    own(from.primaryNodes);
    own(from.gammaNodes);
}

void PrimaryRegion::setSubstep(const Layout& L, int substeps, double dtNew) noexcept {
    // A new substep keeps the half-step velocity (u - uPrev) / dt of the free dofs, and the
    // central-difference coefficients follow it (on the free dofs of L: a layout adopted later
    // is brought up to date by the generation check).
    if (substeps != mSubsteps || dtNew != mDtSub) {
        const double ratio = dtNew / mDtSub;
        for (int d : L.freeDofs) mUPrev[d] = mU[d] - (mU[d] - mUPrev[d]) * ratio;
        mSubsteps = substeps;
        mDtSub = dtNew;
        mCoefGeneration = 0;
    }
    if (mCoefGeneration == L.generation) return;
    const Eigen::VectorXd& mass = mSetup.model.lumpedMass();
    const double alpha = mSetup.model.material().dampingAlpha;
    for (int d : L.freeDofs) {
        mInvDen[d] = 1.0 / (mass[d] + 0.5 * mDtSub * alpha * mass[d]);
        mPrevCoef[d] = mass[d] - 0.5 * mDtSub * alpha * mass[d];
    }
    mCoefGeneration = L.generation;
}

void PrimaryRegion::addSecondaryLoad(int n, const Eigen::Vector3d& force) noexcept {
    for (int k = 0; k < 3; ++k) {
        const int d = 3 * n + k;
        if (mSetup.fixed[sz(d)]) continue;
        mFAcc[d] += force[k];
        if (!mAccMark[sz(n)]) {
            mAccMark[sz(n)] = 1;
            mAccNodes[mAccCount++] = n;
        }
    }
}

void PrimaryRegion::advance(const Layout& L, const Eigen::Vector3d& target,
                            AsyncTickResult& result) noexcept {
    advance(L, target, nullptr, result);
}

void PrimaryRegion::advance(const Layout& L, const Eigen::Vector3d& target,
                            const CouplingSpring* spring, AsyncTickResult& result) noexcept {
    const FemModel& model = mSetup.model;
    const HexMesh& mesh = model.mesh();
    // The spring: valid nodes only; its frequency on P bounds the substep.
    const bool springOn = spring != nullptr && spring->active();
    if (!springOn) mShareLive = false;  // a swap after a tick without the spring corrects nothing
    Eigen::Vector3d aOutside = Eigen::Vector3d::Zero();  // a(u) share of non-P, non-Gamma nodes
    int substeps = mBaseSubsteps;
    double dtNew = mBaseDt;
    double springOmega2 = 0.0;  // the spring's k w^T M^-1 w on P, rad^2/s^2
    if (springOn) {
        const Eigen::VectorXd& mass = model.lumpedMass();
        const double frac0 = shownFraction();
        double w2m = 0.0;
        bool bad = false;
        for (std::size_t i = 0; i < spring->nodes.size(); ++i) {
            const int n = spring->nodes[i];
            const double w = spring->weights[i];
            if (n < 0 || n >= mesh.nodeCount() || !mesh.nodeActive()[sz(n)] || !std::isfinite(w)) {
                bad = true;
                continue;
            }
            if (L.isPrimary[sz(n)]) {
                if (mass[3 * n] > 0.0) w2m += w * w / mass[3 * n];
            } else if (!L.isGamma[sz(n)]) {
                const Eigen::Vector3d un = shown(L, n, frac0);
                if (un.allFinite()) aOutside += w * un;  // unwatched secondary node: counts 0
            }
        }
        if (bad) {
            result.flags |= kAsyncLoadsRefused;
            ++result.loadsRefused;
        }
        springOmega2 = spring->stiffness * w2m;
        const double dtSpring =
            mSetup.options.safetyFactor * criticalTimeStepWith(model, springOmega2);
        const double need = std::ceil(mSetup.options.tickSeconds / dtSpring);
        substeps = std::max(mBaseSubsteps, need < 1e9 ? static_cast<int>(need) : 1 << 30);
        if (substeps > mSetup.options.maxSubsteps) {
            // As ExplicitSolver: maxSubsteps stable substeps, less time than a tick (flagged).
            substeps = mSetup.options.maxSubsteps;
            dtNew = dtSpring;
            result.flags |= kStepSubstepLimit;
        } else {
            dtNew = mSetup.options.tickSeconds / substeps;
        }
    }
    if (mSetup.tled) {
        // As ExplicitSolver with TLED: the primary cells' current stiffness (compression raises
        // it) with the spring's frequency sets the substep; the cap is flagged.
        const double omega =
            mSetup.tled->frequencyBoundCells(mU.data(), L.tledCellDofs, L.tledCellE);
        const double dtTled =
            mSetup.options.safetyFactor * mSetup.tled->criticalTimeStep(omega, springOmega2);
        const double need = std::ceil(mSetup.options.tickSeconds / dtTled);
        if (!(need <= static_cast<double>(mSetup.options.maxSubsteps))) {
            // maxSubsteps substeps of the stable step (less time than a tick), or of a tick's
            // share where the bound is not finite (an inverted cell), as ExplicitSolver.
            substeps = mSetup.options.maxSubsteps;
            const double cap = mSetup.options.tickSeconds / substeps;
            dtNew = std::min(dtNew, std::isfinite(dtTled) && dtTled > 0.0 ? dtTled : cap);
            result.flags |= kStepSubstepLimit;
        } else if (static_cast<int>(need) > substeps) {
            substeps = static_cast<int>(need);
            dtNew = mSetup.options.tickSeconds / substeps;
        }
    }
    setSubstep(L, substeps, dtNew);
    // The spring's share on nodes outside P reaches the secondary as a load, solved a period
    // or two later; a(u) sees the shown secondary values, which answer the share force
    // F~ of an older snapshot. Condensed like Gamma: a_S = a~_S + C (F - F~) with C the
    // secondary's compliance there, so F solves (I + k C) F = k (c - a) + k C F~ (exact in
    // the quasi-static limit; a stiff spring on a lagging secondary otherwise rings, issue 18).
    bool share = false;
    Eigen::Matrix3d shareSolve = Eigen::Matrix3d::Identity();
    Eigen::Vector3d shareShift = Eigen::Vector3d::Zero();
    if (springOn) {
        Eigen::Matrix3d C;
        if (shareCompliance(L, *spring, C)) {
            const double k = spring->stiffness;
            const Eigen::Matrix3d S = (Eigen::Matrix3d::Identity() + k * C).inverse();
            const Eigen::Vector3d shown = mSharePrev + shownFraction() * (mShareCur - mSharePrev);
            if (S.allFinite() && shown.allFinite()) {
                share = true;
                shareSolve = S;
                shareShift = k * (C * shown);
            }
        }
    }
    auto springPoint = [&]() {
        Eigen::Vector3d a = aOutside;
        for (std::size_t i = 0; i < spring->nodes.size(); ++i) {
            const int n = spring->nodes[i];
            if (n < 0 || n >= mesh.nodeCount() || !mesh.nodeActive()[sz(n)]) continue;
            if (L.isPrimary[sz(n)] || L.isGamma[sz(n)])
                a += spring->weights[i] * mU.segment<3>(3 * n);
        }
        return a;
    };
    Eigen::Vector3d impulse = Eigen::Vector3d::Zero();
    const double* ke = model.unitStiffness();
    const Eigen::Map<const Eigen::Matrix<double, 24, 24>, Eigen::Aligned64> K(ke);
    const double beta = model.material().dampingBeta;
    const double dt = mDtSub;
    // Without a spring the tick advances tickSeconds; with the cap biting, substeps of the
    // spring's stable step (less time than asked, flagged) as ExplicitSolver does.
    const double dt2 = dt * dt;
    const std::vector<int>& contactDofs = L.contactDofs;
    for (std::size_t i = 0; i < contactDofs.size(); ++i)
        mContactStart[static_cast<Eigen::Index>(i)] = mU[contactDofs[i]];
    for (int s = 0; s < mSubsteps; ++s) {
        const bool product = s == 0 || !mSetup.options.condensedOncePerTick;
        setGamma(L, mU.data(), mTime, product);
        const double* operand = mU.data();
        if (beta > 0.0) {
            setGamma(L, mUPrev.data(), mTime - dt, product);
            const double b = beta / dt;
            for (int d : L.touchedDofs) mWork[d] = mU[d] + b * (mU[d] - mUPrev[d]);
            operand = mWork.data();
        }
        if (mSetup.tled) {
            // TLED on the cells inside P, the linear element on those touching Gamma; rows of P
            // nodes are whole (P nodes touch primary cells only), the others are not read.
            for (int d : L.touchedDofs) mFInt[d] = 0.0;
            cellRows(L.seamNodes, L.seamCellStart, L.seamCells, L, operand, K);
            mSetup.tled->addCellForces(operand, mFInt.data(), L.tledCellDofs, L.tledCellE);
        } else {
            internalForces(L, operand, K);
        }
        // The contact damper (implicit, on the spring's free P dofs): a(u(n-1)) over them,
        // before the update overwrites u(n-1).
        const bool damperOn = springOn && spring->damping > 0.0;
        Eigen::Vector3d aPrevP = Eigen::Vector3d::Zero();
        if (damperOn) {
            for (std::size_t i = 0; i < spring->nodes.size(); ++i) {
                const int n = spring->nodes[i];
                if (n < 0 || n >= mesh.nodeCount() || !L.isPrimary[sz(n)]) continue;
                for (int k = 0; k < 3; ++k)
                    if (!mSetup.fixed[sz(3 * n + k)])
                        aPrevP[k] += spring->weights[i] * mUPrev[3 * n + k];
            }
        }
        if (springOn) {
            // The spring from this substep's displacement, its target moving with the probe
            // (k (c + v t - a)); on P it acts now (as a negative internal force: mFInt is
            // rebuilt every substep).
            const Eigen::Vector3d a =
                springPoint() - (static_cast<double>(s) * dt) * spring->targetVelocity;
            Eigen::Vector3d F = springForce(*spring, a);
            if ((spring->stiffness * (spring->target - a)).norm() > spring->maxForce)
                result.spring.clamped = true;
            if (share) {
                F = shareSolve * (spring->stiffness * (spring->target - a) + shareShift);
                const double norm = F.norm();
                if (!std::isfinite(norm)) {
                    F.setZero();
                } else if (norm > spring->maxForce) {
                    F *= spring->maxForce / norm;
                    result.spring.clamped = true;
                }
            }
            impulse += dt * F;
            result.spring.endForce = F;
            for (std::size_t i = 0; i < spring->nodes.size(); ++i) {
                const int n = spring->nodes[i];
                if (n < 0 || n >= mesh.nodeCount() || !L.isPrimary[sz(n)]) continue;
                for (int k = 0; k < 3; ++k)
                    if (!mSetup.fixed[sz(3 * n + k)]) mFInt[3 * n + k] -= spring->weights[i] * F[k];
            }
        }
        for (int d : L.freeDofs)
            mUPrev[d] =
                (dt2 * (mFExt[d] - mFInt[d]) + mTwoMass[d] * mU[d] - mPrevCoef[d] * mUPrev[d]) *
                mInvDen[d];
        if (damperOn) {
            // As ExplicitSolver: the rank-one damping b w w^T solved by Sherman-Morrison,
            // u+ = u^ - beta g (w^T u^ - w^T u-) / (1 + beta w^T g), g = D^-1 w, per direction.
            const double bt = 0.5 * dt * spring->damping;
            Eigen::Vector3d aHat = Eigen::Vector3d::Zero(), gamma = Eigen::Vector3d::Zero();
            for (std::size_t i = 0; i < spring->nodes.size(); ++i) {
                const int n = spring->nodes[i];
                if (n < 0 || n >= mesh.nodeCount() || !L.isPrimary[sz(n)]) continue;
                const double w = spring->weights[i];
                for (int k = 0; k < 3; ++k) {
                    if (mSetup.fixed[sz(3 * n + k)]) continue;
                    aHat[k] += w * mUPrev[3 * n + k];
                    gamma[k] += w * w * mInvDen[3 * n + k];
                }
            }
            for (int k = 0; k < 3; ++k) {
                const double scale = bt * (aHat[k] - aPrevP[k]) / (1.0 + bt * gamma[k]);
                for (std::size_t i = 0; i < spring->nodes.size(); ++i) {
                    const int n = spring->nodes[i];
                    if (n < 0 || n >= mesh.nodeCount() || !L.isPrimary[sz(n)] ||
                        mSetup.fixed[sz(3 * n + k)])
                        continue;
                    mUPrev[3 * n + k] -= scale * spring->weights[i] * mInvDen[3 * n + k];
                }
            }
        }
        const double frac = static_cast<double>(s + 1) / mSubsteps;
        for (std::size_t i = 0; i < contactDofs.size(); ++i) {
            const double start = mContactStart[static_cast<Eigen::Index>(i)];
            mUPrev[contactDofs[i]] =
                start + frac * (target[static_cast<Eigen::Index>(i % 3)] - start);
        }
        mU.swap(mUPrev);
        mTime += dt;
        ++result.substeps;
    }
    // Gamma as of now (with the tick's last condensed correction), for nodeDisplacement(); the
    // next substep sets it again before using it.
    setGamma(L, mU.data(), mTime, false);
    if (springOn) {
        // The tick's mean force; its share on nodes outside P enters the secondary's loads.
        const double seconds = mSubsteps * dt;
        result.spring.meanForce = impulse / seconds;
        result.spring.endPoint = springPoint();
        bool outside = false;
        for (std::size_t i = 0; i < spring->nodes.size(); ++i) {
            const int n = spring->nodes[i];
            if (n < 0 || n >= mesh.nodeCount() || !mesh.nodeActive()[sz(n)] || L.isPrimary[sz(n)])
                continue;
            addSecondaryLoad(n, spring->weights[i] * result.spring.meanForce);
            outside = outside || spring->weights[i] > 0.0;
        }
        if (outside) mShareAcc += result.spring.meanForce;  // the share F~ of this period
        mShareLive = share;
        if (share)
            mShareDelta =
                result.spring.endForce - (mSharePrev + shownFraction() * (mShareCur - mSharePrev));
    }
    bool finite = true;
    for (int d : L.freeDofs) finite = finite && std::isfinite(mU[d]);
    if (!finite) {
        for (int d : L.freeDofs) {
            mU[d] = 0.0;
            mUPrev[d] = 0.0;
        }
        result.flags |= kStepDiverged;
    }
    Eigen::Vector3d force = Eigen::Vector3d::Zero();
    for (std::size_t i = 0; i < contactDofs.size(); ++i)
        force[static_cast<Eigen::Index>(i % 3)] += mFInt[contactDofs[i]];
    if (!mSetup.forceDrive) result.contactForce = finite ? force : Eigen::Vector3d::Zero();
}

void PrimaryRegion::takeLoads(const Layout& L, std::span<const NodalLoad> loads,
                              AsyncTickResult& result) noexcept {
    const HexMesh& mesh = mSetup.model.mesh();
    Eigen::Vector3d sum = Eigen::Vector3d::Zero();
    std::size_t taken = 0;
    for (std::size_t i = 0; i < loads.size(); ++i) {
        if (taken >= sz(mSetup.options.maxLoads)) {  // bounded work whatever the caller passes
            result.loadsRefused += static_cast<int>(loads.size() - i);
            break;
        }
        const NodalLoad& load = loads[i];
        const int n = load.node;
        if (n < 0 || n >= mesh.nodeCount() || !mesh.nodeActive()[sz(n)] ||
            !load.force.allFinite()) {
            ++result.loadsRefused;
            continue;
        }
        ++taken;
        sum += load.force;
        const bool primary = L.isPrimary[sz(n)] != 0;
        for (int k = 0; k < 3; ++k) {
            const int d = 3 * n + k;
            if (mSetup.fixed[sz(d)]) continue;  // taken by the support
            if (primary) {
                mFExtDofs[mFExtCount++] = d;  // a repeated dof is listed twice: harmless
                mFExt[d] += load.force[k];
            } else {
                mFAcc[d] += load.force[k];
                if (!mAccMark[sz(n)]) {
                    mAccMark[sz(n)] = 1;
                    mAccNodes[mAccCount++] = n;
                }
            }
        }
    }
    result.contactForce = sum;
    if (result.loadsRefused > 0) result.flags |= kAsyncLoadsRefused;
}

void PrimaryRegion::clearTickLoads() noexcept {
    for (std::size_t i = 0; i < mFExtCount; ++i) mFExt[mFExtDofs[i]] = 0.0;
    mFExtCount = 0;
}

void PrimaryRegion::packLoads(BorderPacket& out, std::uint64_t sequence) noexcept {
    const std::size_t slot = mShareNext++ % mShareSeq.size();
    mShareSeq[slot] = sequence;
    mShareSent[slot] = mShareAcc / static_cast<double>(mSetup.period);
    mShareAcc.setZero();
    // The period's mean load on each secondary dof (its impulse over the period).
    const double inv = 1.0 / mSetup.period;
    int count = 0;
    for (std::size_t i = 0; i < mAccCount; ++i) {
        const int n = mAccNodes[i];
        mAccMark[sz(n)] = 0;
        for (int k = 0; k < 3; ++k) {
            const int d = 3 * n + k;
            const double f = mFAcc[d];
            mFAcc[d] = 0.0;
            if (f == 0.0) continue;
            out.loadDofs[sz(count)] = d;
            out.loadValues[sz(count)] = f * inv;
            ++count;
        }
    }
    mAccCount = 0;
    out.loadCount = count;
}

void PrimaryRegion::readBorder(const Layout& L, double* out) const noexcept {
    for (std::size_t i = 0; i < L.borderDofs.size(); ++i) out[i] = mU[L.borderDofs[i]];
}

}  // namespace palp::fem
