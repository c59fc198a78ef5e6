#include "regions/secondary_region.h"

#include <ctime>

#include "index_cast.h"
#include "regions/async_capacitance.h"

namespace palp::fem {

namespace {

double threadCpuSeconds() noexcept {
    timespec cpu{};
    clock_gettime(CLOCK_THREAD_CPUTIME_ID, &cpu);
    return static_cast<double>(cpu.tv_sec) + 1e-9 * static_cast<double>(cpu.tv_nsec);
}

}  // namespace

SecondaryRegion::SecondaryRegion(const AsyncSetup& setup)
    : mSetup(setup), mUC(Eigen::VectorXd::Zero(setup.coarseDofs)), mVC(mUC), mAC(mUC) {}

bool SecondaryRegion::solve(Layout& L, const double* borderValues, const BorderPacket* loads,
                            double* gammaOut, double* watchOut) noexcept {
    const auto begin = std::chrono::steady_clock::now();
    const double cpuBegin = threadCpuSeconds();
    const int unknowns = static_cast<int>(L.unknownCoarseDof.size());
    int iterations = 0;
    bool ok = true;
    const int loadCount = loads != nullptr ? loads->loadCount : 0;
    const bool watching = watchOut != nullptr && L.interpWatch.rows() > 0;
    // Gamma (and the watched nodes) alone when their responses to the border are at hand and
    // the loads on secondary nodes, if any, are answered from the capacitance zone block (a
    // sliding contact's spring share on the surface); other loads need the whole field.
    const bool gammaKnown =
        L.gammaResponse.size() > 0 || (L.global != nullptr && L.gammaBasis.block.size() > 0 &&
                                       !mSetup.options.secondaryFullField);
    const bool responses = gammaKnown && (!watching || L.watchResponse.size() > 0 || L.watchInZone);
    bool direct = responses && loadCount == 0;
    if (responses && loadCount > 0 && L.global != nullptr)
        direct = L.global->loadResponse(L, *loads);
    if (direct) {
        if (loadCount == 0) L.loaded = false;
        ok = solveDirect(L, borderValues, gammaOut, watching ? watchOut : nullptr);
    } else if (unknowns > 0) {
        ok = solveField(L, borderValues, loads, iterations);
    }
    if (ok && !direct) {
        const Eigen::Index ng = static_cast<Eigen::Index>(L.gammaDofs.size());
        Eigen::Map<Eigen::VectorXd> out(gammaOut, ng);
        if (unknowns > 0) {
            out.noalias() = L.interpGamma * L.x;
        } else {
            out.setZero();
        }
    }
    if (ok && !direct && watchOut != nullptr) {
        Eigen::Map<Eigen::VectorXd> out(watchOut, L.interpWatch.rows());
        if (unknowns > 0) {
            out.noalias() = L.interpWatch * L.x;
        } else {
            out.setZero();
        }
    }
    const double seconds =
        std::chrono::duration<double>(std::chrono::steady_clock::now() - begin).count();
    mLastSolve.store(seconds, std::memory_order_relaxed);
    mLastSolveCpu.store(threadCpuSeconds() - cpuBegin, std::memory_order_relaxed);
    if (seconds > mMaxSolve.load(std::memory_order_relaxed))
        mMaxSolve.store(seconds, std::memory_order_relaxed);
    mLastIterations.store(iterations, std::memory_order_relaxed);
    if (ok) mSolves.fetch_add(1, std::memory_order_release);
    return ok;
}

bool SecondaryRegion::solveDirect(Layout& L, const double* borderValues, double* gammaOut,
                                  double* watchOut) noexcept {
    // Quasi-static: Gamma = R u_B exactly (R from the factorisation, at set-up).
    const Eigen::Index nb = static_cast<Eigen::Index>(L.borderDofs.size());
    for (Eigen::Index i = 0; i < nb; ++i) L.border[i] = borderValues[i];
    // With loads on zone dofs (L.loaded) their part of the field adds, at zone unknowns.
    auto addLoads = [&](const RowSparseMatrix& rows, Eigen::Map<Eigen::VectorXd>& out) {
        if (!L.loaded) return;
        for (Eigen::Index r = 0; r < rows.rows(); ++r)
            for (RowSparseMatrix::InnerIterator it(rows, r); it; ++it)
                out[r] +=
                    it.value() * L.loadZone[L.global->zonePosition(static_cast<int>(it.col()))];
    };
    Eigen::Map<Eigen::VectorXd> out(gammaOut, static_cast<Eigen::Index>(L.gammaDofs.size()));
    if (L.gammaResponse.size() > 0) {
        out.noalias() = L.gammaResponse * L.border;
    } else {
        // Capacitance: G = gammaBasis Q, factored (rank |J|).
        L.capZ.noalias() = L.capQ * L.border;
        L.gammaBasis.apply(L.capZ, L.capY, out.data());
    }
    addLoads(L.interpGamma, out);
    bool ok = out.allFinite();
    if (watchOut != nullptr && L.watchResponse.size() == 0) {
        // Capacitance secondary: the watched rows of the zone field (border and loads).
        L.global->zoneField(L, L.zoneWork);
        Eigen::Map<Eigen::VectorXd> w(watchOut, L.interpWatch.rows());
        for (Eigen::Index r = 0; r < L.interpWatch.rows(); ++r) {
            double s = 0.0;
            for (RowSparseMatrix::InnerIterator it(L.interpWatch, r); it; ++it)
                s += it.value() * L.zoneWork[L.global->zonePosition(static_cast<int>(it.col()))];
            w[r] = s;
        }
        ok = ok && w.allFinite();
    } else if (watchOut != nullptr) {
        Eigen::Map<Eigen::VectorXd> w(watchOut, L.watchResponse.rows());
        w.noalias() = L.watchResponse * L.border;
        addLoads(L.interpWatch, w);
        ok = ok && w.allFinite();
    }
    L.fieldStale = true;
    return ok;
}

bool SecondaryRegion::solveField(Layout& L, const double* borderValues, const BorderPacket* loads,
                                 int& iterations) noexcept {
    const AsyncRegionsOptions& o = mSetup.options;
    const NewmarkCoefficients& nm = mSetup.nm;
    const int loadCount = loads != nullptr ? loads->loadCount : 0;
    try {
        warmStart(L);
        const Eigen::Index nb = static_cast<Eigen::Index>(L.borderDofs.size());
        for (Eigen::Index i = 0; i < nb; ++i) L.border[i] = borderValues[i];
        const bool dynamic = o.secondaryIntegrator != Integrator::quasiStatic;
        const double alpha = mSetup.model.material().dampingAlpha;
        const double beta = mSetup.model.material().dampingBeta;
        L.rhs.noalias() = -mSetup.sK * (L.kcb * L.border);
        // External loads on secondary dofs, restricted with I^T (rows of P dofs are empty).
        for (int i = 0; i < loadCount; ++i) {
            const double f = loads->loadValues[sz(i)];
            // Loads gathered on nodes this layout makes primary are dropped (the capacitance
            // layouts share the whole body's interpolation, whose P rows are not empty).
            if (L.isPrimary[sz(loads->loadDofs[sz(i)] / 3)]) continue;
            for (RowSparseMatrix::InnerIterator it(L.interp, loads->loadDofs[sz(i)]); it; ++it)
                L.rhs[it.col()] += it.value() * f;
        }
        if (dynamic) {
            L.yc = nm.a1 * L.x + nm.a4 * L.v + nm.a5 * L.a;
            L.ym = nm.a0 * L.x + nm.a2 * L.v + nm.a3 * L.a + alpha * L.yc;
            L.rhs.noalias() += L.mc * L.ym;
            if (beta > 0.0) L.rhs.noalias() += beta * (L.kc * L.yc);
        }
        if (L.global != nullptr) {
            if (!L.global->solve(L, L.rhs, L.xNew)) return false;
        } else if (o.secondarySolver == LinearSolverKind::cholmod) {
            L.xNew = L.cholmod.solve(L.rhs);
        } else {
            // Warm-started Jacobi PCG on the arena's TBB threads.
            L.xNew = L.x;
            iterations = solveJacobiPcg(L.rowA, L.inverseDiagonal, L.rhs, L.xNew, L.pcg,
                                        o.pcgRelativeTolerance, o.pcgMaxIterations);
        }
        if (!L.xNew.allFinite()) return false;
        if (dynamic) advanceScheme(L);
        for (std::size_t i = 0; i < L.unknownCoarseDof.size(); ++i) {
            const Eigen::Index k = static_cast<Eigen::Index>(i);
            const int cd = L.unknownCoarseDof[i];
            mUC[cd] = L.xNew[k];
            mVC[cd] = L.v[k];
            mAC[cd] = L.a[k];
        }
        L.x = L.xNew;
        L.fieldStale = false;
        L.loaded = false;
        return true;
    } catch (...) {
        return false;
    }
}

void SecondaryRegion::advanceScheme(Layout& L) noexcept {
    // Velocity and acceleration at the end of the period from x -> xNew.
    const NewmarkCoefficients& nm = mSetup.nm;
    const double dt = mSetup.periodSeconds;
    if (mSetup.options.secondaryIntegrator == Integrator::newmark) {
        L.ym = nm.a0 * (L.xNew - L.x) - nm.a2 * L.v - nm.a3 * L.a;  // a(n+1)
        L.v += dt * 0.5 * (L.a + L.ym);
        L.a = L.ym;
    } else {
        L.ym = (L.xNew - L.x) / dt;  // v(n+1)
        L.a = (L.ym - L.v) / dt;
        L.v = L.ym;
    }
}

void SecondaryRegion::refreshField(Layout& L) {
    if (!L.fieldStale) return;
    L.fieldStale = false;
    if (L.unknownCoarseDof.empty()) return;
    L.rhs.noalias() = -mSetup.sK * (L.kcb * L.border);
    if (L.loaded) L.rhs += L.loadRhs;  // the last direct solve's loads (zone block)
    if (L.global != nullptr) {
        L.global->solve(L, L.rhs, L.x);
    } else {
        L.x = L.cholmod.solve(L.rhs);
    }
    for (std::size_t i = 0; i < L.unknownCoarseDof.size(); ++i)
        mUC[L.unknownCoarseDof[i]] = L.x[static_cast<Eigen::Index>(i)];
}

void SecondaryRegion::warmStart(Layout& L) const noexcept {
    for (std::size_t i = 0; i < L.unknownCoarseDof.size(); ++i) {
        const Eigen::Index k = static_cast<Eigen::Index>(i);
        const int cd = L.unknownCoarseDof[i];
        L.x[k] = mUC[cd];
        L.v[k] = mVC[cd];
        L.a[k] = mAC[cd];
    }
}

void SecondaryRegion::prepareEntry(Layout& from, Layout& next,
                                   std::chrono::steady_clock::time_point begin) {
    // Entry state: nodes of the new P and Gamma that were interior secondary nodes of `from`
    // take the secondary's latest solution (the servo keeps its own values for the others).
    // A capacitance layout whose field lags the border gives those values from its zone block
    // (no solve); otherwise the field is brought up to date first.
    next.entryDofs.clear();
    next.entryValues.clear();
    next.entryResponse.resize(0, 0);
    next.entryBasis.clear();
    next.entryQ.resize(0, 0);
    bool done = false;
    if (from.global != nullptr && from.fieldStale) {
        forEachEnteringDofIndex(from, next, mSetup.fixed,
                                [&](int d) { next.entryDofs.push_back(d); });
        done = from.global->borderFieldAt(from, next.entryDofs, next.entryValues);
        if (!done) next.entryDofs.clear();
    }
    if (!done) {
        refreshField(from);
        forEachEnteringDof(from, next, mSetup.fixed, [&](int d, double value) {
            next.entryDofs.push_back(d);
            next.entryValues.push_back(value);
        });
    }
    // Their response to the border, so the servo can bring them to the border it shows at the
    // swap (the values answer the last solve's border: up to a period old, more when the
    // layout waits). Capacitance layouts only (from the zone block); others enter as solved.
    if (!next.entryDofs.empty()) {
        bool known = false;
        if (from.global != nullptr) {
            known =
                from.global->borderResponseAt(from, next.entryDofs, next.entryBasis, next.entryQ);
        } else if (!from.unknownCoarseDof.empty() &&
                   mSetup.options.secondaryIntegrator == Integrator::quasiStatic &&
                   mSetup.options.secondarySolver == LinearSolverKind::cholmod) {
            // The layout's own factor: E = -I_e A^-1 sK K_SB = -(A^-1 I_e^T)^T sK K_SB, one
            // solve with |entry| right-hand sides (A is symmetric).
            const Eigen::Index ne = static_cast<Eigen::Index>(next.entryDofs.size());
            Eigen::MatrixXd rows = Eigen::MatrixXd::Zero(from.interp.cols(), ne);
            for (Eigen::Index i = 0; i < ne; ++i)
                for (RowSparseMatrix::InnerIterator it(from.interp,
                                                       next.entryDofs[sz(static_cast<int>(i))]);
                     it; ++it)
                    rows(it.col(), i) = it.value();
            const Eigen::MatrixXd y = from.cholmod.solve(rows);
            known = from.cholmod.info() == Eigen::Success && y.allFinite();
            if (known) next.entryResponse = -mSetup.sK * (from.kcb.transpose() * y).transpose();
        }
        if (known) {
            next.entryBorder = from.border;
        } else {
            next.entryResponse.resize(0, 0);
            next.entryBasis.clear();
            next.entryQ.resize(0, 0);
        }
    }
    // The spring share's correction at the swap (applyShareCorrection): the dofs it moves
    // (a node stops at its first dof outside the zone) and their rows of I W(., J).
    next.shareDofs.clear();
    next.shareBasis.clear();
    if (from.global != nullptr) {
        const RowSparseMatrix& I = from.global->interpolation();
        auto add = [&](int n) {
            if (from.isPrimary[sz(n)]) return;
            for (int k = 0; k < 3; ++k) {
                const int d = 3 * n + k;
                if (mSetup.fixed[sz(d)]) continue;
                for (RowSparseMatrix::InnerIterator it(I, d); it; ++it)
                    if (from.global->zonePosition(static_cast<int>(it.col())) < 0) return;
                next.shareDofs.push_back(d);
            }
        };
        for (int n : next.primaryNodes) add(n);
        for (int n : next.gammaNodes) add(n);
        if (!from.global->zoneRowsAt(next.shareDofs, from.capJ, next.shareBasis))
            next.shareDofs.clear();
    }
    // Warm state of the secondary in its own indexing.
    warmStart(next);
    mLastPrepare.store(
        std::chrono::duration<double>(std::chrono::steady_clock::now() - begin).count(),
        std::memory_order_relaxed);
    mPrepared.fetch_add(1, std::memory_order_release);
}

void SecondaryRegion::takeFromPrimary(const Layout& from, Layout& to, const Eigen::VectorXd& u,
                                      const Eigen::VectorXd& uPrev, double dtSub) noexcept {
    // Coarse unknowns leaving the primary take the primary's values.
    const HexMesh& mesh = mSetup.model.mesh();
    const std::array<int, 3>& cc = mSetup.coarseCounts;
    const int lod = mSetup.lod;
    for (int cd : to.unknownCoarseDof) {
        const int cn = cd / 3, k = cd % 3;
        const int X = cn % cc[0], Y = (cn / cc[0]) % cc[1], Z = cn / (cc[0] * cc[1]);
        const int fine = mesh.node(X * lod, Y * lod, Z * lod);
        if (!from.isPrimary[sz(fine)]) continue;
        const int d = 3 * fine + k;
        mUC[cd] = u[d];
        mVC[cd] = (u[d] - uPrev[d]) / dtSub;
        mAC[cd] = 0.0;
    }
    warmStart(to);
}

AsyncSecondaryStats SecondaryRegion::stats(std::uint64_t used) const noexcept {
    AsyncSecondaryStats s;
    s.solves = mSolves.load(std::memory_order_acquire);
    s.used = used;
    s.lastSolveSeconds = mLastSolve.load(std::memory_order_relaxed);
    s.maxSolveSeconds = mMaxSolve.load(std::memory_order_relaxed);
    s.lastSolveCpuSeconds = mLastSolveCpu.load(std::memory_order_relaxed);
    s.lastIterations = mLastIterations.load(std::memory_order_relaxed);
    s.layoutsPrepared = mPrepared.load(std::memory_order_acquire);
    s.lastPrepareSeconds = mLastPrepare.load(std::memory_order_relaxed);
    return s;
}

}  // namespace palp::fem
