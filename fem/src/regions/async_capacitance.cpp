#include "regions/async_capacitance.h"

#include <cholmod.h>

#include <Eigen/LU>
#include <algorithm>
#include <chrono>
#include <cmath>
#include <sstream>

#include "index_cast.h"
#include "palp/base/error.h"
#include "regions/coarse_weights.h"

namespace palp::fem {

namespace {

using Triplet = Eigen::Triplet<double, int>;

double secondsSince(std::chrono::steady_clock::time_point t) {
    return std::chrono::duration<double>(std::chrono::steady_clock::now() - t).count();
}

/// `I_rows W(., J)` factored into @p out (interp_basis.h): the zone positions the rows
/// interpolate from (T, first-use order), the block W(T, J) and the rows' weights on T.
/// @p rows(r, f) calls f(unknown, weight) for each entry of row r. false (out cleared) when a
/// row interpolates from outside the zone.
template <class Rows>
bool zoneBasis(Eigen::Index rowCount, Rows&& rows, const std::vector<int>& capJ,
               const std::vector<int>& zonePos, const Eigen::MatrixXd& W, InterpBasis& out) {
    out.clear();
    std::vector<int> cols;  // T, as zone positions
    std::vector<int> slot(sz(static_cast<int>(W.rows())), -1);
    bool inside = true;
    out.start.reserve(sz(static_cast<int>(rowCount)) + 1);
    for (Eigen::Index r = 0; r < rowCount && inside; ++r) {
        rows(r, [&](int u, double w) {
            const int p = zonePos[sz(u)];
            if (p < 0) {
                inside = false;
                return;
            }
            if (slot[sz(p)] < 0) {
                slot[sz(p)] = static_cast<int>(cols.size());
                cols.push_back(p);
            }
            out.col.push_back(slot[sz(p)]);
            out.weight.push_back(w);
        });
        out.start.push_back(static_cast<int>(out.col.size()));
    }
    if (!inside) {
        out.clear();
        return false;
    }
    const Eigen::Index nj = static_cast<Eigen::Index>(capJ.size());
    out.pos = cols;
    out.block.resize(static_cast<Eigen::Index>(cols.size()), nj);
    for (Eigen::Index j = 0; j < nj; ++j) {
        const int pj = zonePos[sz(capJ[sz(static_cast<int>(j))])];
        for (std::size_t i = 0; i < cols.size(); ++i)
            out.block(static_cast<Eigen::Index>(i), j) = W(cols[i], pj);
    }
    return true;
}

}  // namespace

/// The raw CHOLMOD factor (ordered with the zone last) and the solve's reusable workspaces.
struct GlobalSecondary::Factor {
    Factor() { cholmod_start(&common); }
    ~Factor() {
        cholmod_free_dense(&x, &common);
        cholmod_free_dense(&y, &common);
        cholmod_free_dense(&e, &common);
        cholmod_free_factor(&factor, &common);
        cholmod_finish(&common);
    }
    Factor(const Factor&) = delete;
    Factor& operator=(const Factor&) = delete;
    cholmod_common common{};
    cholmod_factor* factor = nullptr;
    cholmod_dense *x = nullptr, *y = nullptr, *e = nullptr;
};

GlobalSecondary::GlobalSecondary(const AsyncSetup& setup, const SparseMatrix& stiffness,
                                 const std::vector<int>& zoneCoarseNodes)
    : mSetup(setup), mFactor(std::make_unique<Factor>()) {
    // Interpolation of every free fine dof from the corners of an active coarse cell holding
    // its node (the weights are those of the lattice face the node lies in, so any such cell
    // gives the same row, and a layout's secondary rows are these rows).
    const HexMesh& mesh = setup.model.mesh();
    const int nodes = mesh.nodeCount();
    const auto& active = mesh.nodeActive();
    const Eigen::VectorXd& mass = setup.model.lumpedMass();
    const int lod = setup.lod;
    const std::array<int, 3>& cc = setup.coarseCounts;
    auto coarseCellActive = [&](int I, int J, int K) {
        for (int k = K * lod; k < (K + 1) * lod; ++k)
            for (int j = J * lod; j < (J + 1) * lod; ++j)
                for (int i = I * lod; i < (I + 1) * lod; ++i)
                    if (mesh.cellActive(mesh.cell(i, j, k))) return true;
        return false;
    };
    mUnknownOf.assign(sz(setup.coarseDofs), -1);
    std::vector<Triplet> trip;
    for (int n = 0; n < nodes; ++n) {
        if (!active[sz(n)]) continue;
        const auto ijk = mesh.nodeCoords(n);
        std::array<std::array<int, 2>, 3> cand{};
        std::array<int, 3> count{};
        for (int a = 0; a < 3; ++a) {
            const int q = ijk[sz(a)] / lod;
            if (q < cc[sz(a)] - 1) cand[sz(a)][sz(count[sz(a)]++)] = q;
            if (ijk[sz(a)] % lod == 0 && q - 1 >= 0) cand[sz(a)][sz(count[sz(a)]++)] = q - 1;
        }
        int I = -1, J = -1, K = -1;
        for (int a = 0; a < count[0] && I < 0; ++a)
            for (int b = 0; b < count[1] && I < 0; ++b)
                for (int e = 0; e < count[2] && I < 0; ++e)
                    if (coarseCellActive(cand[0][sz(a)], cand[1][sz(b)], cand[2][sz(e)])) {
                        I = cand[0][sz(a)];
                        J = cand[1][sz(b)];
                        K = cand[2][sz(e)];
                    }
        std::array<double, 8> weight{};
        if (I < 0 || !coarseWeights(mesh, lod, ijk, I, J, K, weight)) continue;
        for (int k = 0; k < 3; ++k) {
            const int d = 3 * n + k;
            if (setup.fixed[sz(d)] || mass[d] <= 0.0) continue;
            for (int corner = 0; corner < 8; ++corner) {
                const double w = weight[sz(corner)];
                if (w == 0.0) continue;
                const int X = I + (corner & 1), Y = J + ((corner >> 1) & 1), Z = K + (corner >> 2);
                const int fineDof = 3 * mesh.node(X * lod, Y * lod, Z * lod) + k;
                if (setup.fixed[sz(fineDof)]) continue;
                const int coarseDof = 3 * (X + cc[0] * (Y + cc[1] * Z)) + k;
                int& idx = mUnknownOf[sz(coarseDof)];
                if (idx < 0) {
                    idx = static_cast<int>(mUnknownCoarseDof.size());
                    mUnknownCoarseDof.push_back(coarseDof);
                }
                trip.emplace_back(d, idx, w);
            }
        }
    }
    const int n = static_cast<int>(mUnknownCoarseDof.size());
    mInterpCol.resize(setup.model.dofCount(), n);
    mInterpCol.setFromTriplets(trip.begin(), trip.end());
    mInterp = mInterpCol;
    const SparseMatrix interpT = mInterpCol.transpose();
    mA = SparseMatrix(interpT * stiffness) * mInterpCol;
    mA.makeCompressed();

    // The zone's unknowns, ordered last by CAMD (constraint set 1).
    mZonePos.assign(sz(n), -1);
    std::vector<int> member(sz(n), 0);
    int zone = 0;
    for (int cn : zoneCoarseNodes) {
        for (int k = 0; k < 3; ++k) {
            const int u = mUnknownOf[sz(3 * cn + k)];
            if (u >= 0 && member[sz(u)] == 0) {
                member[sz(u)] = 1;
                ++zone;
            }
        }
    }
    const auto begin = std::chrono::steady_clock::now();
    SparseMatrix lower = mA.triangularView<Eigen::Lower>();
    lower.makeCompressed();
    cholmod_sparse a{};
    a.nrow = a.ncol = sz(n);
    a.nzmax = sz(static_cast<int>(lower.nonZeros()));
    a.p = lower.outerIndexPtr();
    a.i = lower.innerIndexPtr();
    a.x = lower.valuePtr();
    a.stype = -1;
    a.itype = CHOLMOD_INT;
    a.xtype = CHOLMOD_REAL;
    a.dtype = CHOLMOD_DOUBLE;
    a.sorted = 1;
    a.packed = 1;
    cholmod_common& c = mFactor->common;
    std::vector<int> perm(sz(n));
    c.nmethods = 1;
    c.method[0].ordering = CHOLMOD_GIVEN;
    c.postorder = 0;
    c.supernodal = CHOLMOD_SUPERNODAL;
    bool ok = cholmod_camd(&a, nullptr, 0, member.data(), perm.data(), &c) != 0;
    if (ok) mFactor->factor = cholmod_analyze_p(&a, perm.data(), nullptr, 0, &c);
    ok = ok && mFactor->factor != nullptr && cholmod_factorize(&a, mFactor->factor, &c) != 0 &&
         c.status == CHOLMOD_OK && mFactor->factor->minor == sz(n) && mFactor->factor->is_super;
    if (!ok) {
        std::ostringstream s;
        s << "async regions secondary: expected a positive definite system, found a failed "
             "CHOLMOD factorisation ("
          << n << " unknowns; do the supports remove every rigid-body motion?)";
        throw ValueError(s.str());
    }
    mFactoriseSeconds = secondsSince(begin);

    // W = (A^-1)_TT = L_TT^-T L_TT^-1 from the factor's last zone x zone block.
    const auto zoneBegin = std::chrono::steady_clock::now();
    const cholmod_factor& f = *mFactor->factor;
    const int* fperm = static_cast<const int*>(f.Perm);
    const int first = n - zone;
    for (int p = first; p < n; ++p) {
        if (!member[sz(fperm[p])]) throw ValueError("async regions secondary: zone not last");
        mZonePos[sz(fperm[p])] = p - first;
    }
    Eigen::MatrixXd ltt = Eigen::MatrixXd::Zero(zone, zone);
    const int* super = static_cast<const int*>(f.super);
    const int* pi = static_cast<const int*>(f.pi);
    const int* px = static_cast<const int*>(f.px);
    const int* rows = static_cast<const int*>(f.s);
    const double* values = static_cast<const double*>(f.x);
    for (std::size_t s = 0; s < f.nsuper; ++s) {
        const int k1 = super[s], k2 = super[s + 1];
        if (k2 <= first) continue;
        const int nsrow = pi[s + 1] - pi[s];
        for (int j = std::max(k1, first); j < k2; ++j) {
            const double* col = values + px[s] + static_cast<std::ptrdiff_t>(j - k1) * nsrow;
            for (int r = 0; r < nsrow; ++r) {
                const int row = rows[pi[s] + r];
                if (row >= j) ltt(row - first, j - first) = col[r];
            }
        }
    }
    Eigen::MatrixXd linv = Eigen::MatrixXd::Identity(zone, zone);
    ltt.triangularView<Eigen::Lower>().solveInPlace(linv);
    mW = linv.transpose() * linv;
    mZoneSeconds = secondsSince(zoneBegin);
    mY = Eigen::VectorXd::Zero(n);
    mR = mY;
    mBz = Eigen::VectorXd::Zero(zone);
    mVj = mBz;
    mTouched.reserve(sz(zone));
    mMark.assign(sz(zone), 0);
}

GlobalSecondary::~GlobalSecondary() = default;

bool GlobalSecondary::solveA(const double* b, double* x) const noexcept {
    Factor& F = *mFactor;
    const std::size_t n = mUnknownCoarseDof.size();
    cholmod_dense rhs{};
    rhs.nrow = n;
    rhs.ncol = 1;
    rhs.nzmax = n;
    rhs.d = n;
    rhs.x = const_cast<double*>(b);
    rhs.xtype = CHOLMOD_REAL;
    rhs.dtype = CHOLMOD_DOUBLE;
    if (!cholmod_solve2(CHOLMOD_A, F.factor, &rhs, nullptr, &F.x, nullptr, &F.y, &F.e, &F.common))
        return false;
    std::copy_n(static_cast<const double*>(F.x->x), n, x);
    return true;
}

bool GlobalSecondary::solve(const Layout& L, const Eigen::VectorXd& rhs,
                            Eigen::VectorXd& x) const noexcept {
    // y = A^-1 b; x = y - A^-1 E_J (H D) y_J.
    if (!solveA(rhs.data(), mY.data())) return false;
    const Eigen::Index nj = static_cast<Eigen::Index>(L.capJ.size());
    mR.setZero();
    for (Eigen::Index i = 0; i < nj; ++i) {
        double s = 0.0;
        for (Eigen::Index j = 0; j < nj; ++j)
            s += L.capHD(i, j) * mY[L.capJ[sz(static_cast<int>(j))]];
        mR[L.capJ[sz(static_cast<int>(i))]] = s;
    }
    if (!solveA(mR.data(), x.data())) return false;
    x = mY - x;
    return x.allFinite();
}

bool GlobalSecondary::loadResponse(Layout& L, const BorderPacket& loads) const noexcept {
    // b = I_S^T f on the zone (rows of P nodes dropped), then y = W b, x_T = y - W_TJ H D y_J.
    L.loaded = false;
    L.loadRhs.setZero();
    for (int p : mTouched) {
        mBz[p] = 0.0;
        mMark[sz(p)] = 0;
    }
    mTouched.clear();
    for (int i = 0; i < loads.loadCount; ++i) {
        const int d = loads.loadDofs[sz(i)];
        if (L.isPrimary[sz(d / 3)]) continue;
        const double f = loads.loadValues[sz(i)];
        for (RowSparseMatrix::InnerIterator it(mInterp, d); it; ++it) {
            const int u = static_cast<int>(it.col());
            const int p = mZonePos[sz(u)];
            if (p < 0) {
                L.loadRhs.setZero();
                return false;
            }
            if (!mMark[sz(p)]) {
                mMark[sz(p)] = 1;
                mTouched.push_back(p);
            }
            mBz[p] += it.value() * f;
            L.loadRhs[u] += it.value() * f;
        }
    }
    Eigen::VectorXd& x = L.loadZone;
    x.setZero();
    if (mTouched.empty()) return true;
    for (int p : mTouched) x.noalias() += mBz[p] * mW.col(p);
    const Eigen::Index nj = static_cast<Eigen::Index>(L.capJ.size());
    auto vj = mVj.head(nj);
    for (Eigen::Index j = 0; j < nj; ++j) vj[j] = x[mZonePos[sz(L.capJ[sz(static_cast<int>(j))])]];
    mR.head(nj).noalias() = L.capHD * vj;  // mR: free work here (solve() zeroes it first)
    for (Eigen::Index j = 0; j < nj; ++j)
        x.noalias() -= mR[j] * mW.col(mZonePos[sz(L.capJ[sz(static_cast<int>(j))])]);
    L.loaded = x.allFinite();
    return L.loaded;
}

void GlobalSecondary::zoneField(const Layout& L, Eigen::VectorXd& out) const noexcept {
    // x_T = W_TJ (Q u_B) (+ the loads' part).
    const Eigen::Index nj = static_cast<Eigen::Index>(L.capJ.size());
    auto v = mVj.head(nj);
    if (L.capQ.size() > 0) {
        v.noalias() = L.capQ * L.border;
    } else {
        v.setZero();
    }
    if (L.loaded) {
        out = L.loadZone;
    } else {
        out.setZero();
    }
    for (Eigen::Index j = 0; j < nj; ++j)
        out.noalias() += v[j] * mW.col(mZonePos[sz(L.capJ[sz(static_cast<int>(j))])]);
}

bool GlobalSecondary::borderFieldAt(const Layout& L, const std::vector<int>& dofs,
                                    std::vector<double>& values) const {
    // x = A^-1 E_J Q u_B, so x_u = W(u, J) (Q u_B) at zone unknowns u.
    for (int d : dofs)
        for (RowSparseMatrix::InnerIterator it(mInterp, d); it; ++it)
            if (mZonePos[sz(static_cast<int>(it.col()))] < 0) return false;
    const Eigen::Index nj = static_cast<Eigen::Index>(L.capJ.size());
    Eigen::VectorXd v = Eigen::VectorXd::Zero(nj);
    if (L.capQ.size() > 0) v = L.capQ * L.border;
    values.clear();
    for (int d : dofs) {
        double s = 0.0;
        for (RowSparseMatrix::InnerIterator it(mInterp, d); it; ++it) {
            const int pu = mZonePos[sz(static_cast<int>(it.col()))];
            double xu = 0.0;
            for (Eigen::Index j = 0; j < nj; ++j)
                xu += mW(pu, mZonePos[sz(L.capJ[sz(static_cast<int>(j))])]) * v[j];
            if (L.loaded) xu += L.loadZone[pu];
            s += it.value() * xu;
        }
        values.push_back(s);
    }
    return true;
}

bool GlobalSecondary::zoneRowsAt(const std::vector<int>& dofs, const std::vector<int>& capJ,
                                 InterpBasis& basis) const {
    return zoneBasis(
        static_cast<Eigen::Index>(dofs.size()),
        [&](Eigen::Index r, auto&& f) {
            for (RowSparseMatrix::InnerIterator it(mInterp, dofs[sz(static_cast<int>(r))]); it;
                 ++it)
                f(static_cast<int>(it.col()), it.value());
        },
        capJ, mZonePos, mW, basis);
}

bool GlobalSecondary::borderResponseAt(const Layout& L, const std::vector<int>& dofs,
                                       InterpBasis& basis, Eigen::MatrixXd& q) const {
    // x = A^-1 E_J Q u_B: the rows of I W_(.,J) at the dofs (factored), times Q.
    basis.clear();
    q.resize(0, 0);
    const Eigen::Index nj = static_cast<Eigen::Index>(L.capJ.size());
    const Eigen::Index nb = static_cast<Eigen::Index>(L.borderDofs.size());
    const bool coupled = L.capQ.rows() == nj && L.capQ.cols() == nb && nj > 0;
    // No response (no border coupling): a zero-rank factorisation.
    if (!zoneRowsAt(dofs, coupled ? L.capJ : std::vector<int>{}, basis)) return false;
    if (coupled) {
        q = L.capQ;
    } else {
        q = Eigen::MatrixXd::Zero(0, nb);
    }
    return true;
}

bool GlobalSecondary::prepareLayout(Layout& L, const std::vector<int>& primaryCoarseCells,
                                    const SparseMatrix& stiffness) const {
    const AsyncRegionsOptions& o = mSetup.options;
    const std::array<int, 3>& cc = mSetup.coarseCounts;
    const int n = static_cast<int>(mUnknownCoarseDof.size());
    // J: the unknowns at the corners of the primary coarse cells, all in the zone.
    std::vector<int> posInJ(sz(n), -1);
    L.capJ.clear();
    const int ccx = cc[0] - 1, ccy = cc[1] - 1;
    for (int cell : primaryCoarseCells) {
        const int I = cell % ccx, J = (cell / ccx) % ccy, K = cell / (ccx * ccy);
        for (int corner = 0; corner < 8; ++corner) {
            const int X = I + (corner & 1), Y = J + ((corner >> 1) & 1), Z = K + (corner >> 2);
            for (int k = 0; k < 3; ++k) {
                const int u = mUnknownOf[sz(3 * (X + cc[0] * (Y + cc[1] * Z)) + k)];
                if (u < 0 || posInJ[sz(u)] >= 0) continue;
                if (mZonePos[sz(u)] < 0) return false;
                posInJ[sz(u)] = 0;
                L.capJ.push_back(u);
            }
        }
    }
    std::sort(L.capJ.begin(), L.capJ.end());
    const int nj = static_cast<int>(L.capJ.size());
    for (int j = 0; j < nj; ++j) posInJ[sz(L.capJ[sz(j)])] = j;
    // B: the interpolation's columns J on the secondary rows (P rows dropped).
    std::vector<Triplet> bt;
    for (int j = 0; j < nj; ++j) {
        for (SparseMatrix::InnerIterator it(mInterpCol, L.capJ[sz(j)]); it; ++it) {
            if (!L.isPrimary[sz(static_cast<int>(it.row()) / 3)])
                bt.emplace_back(static_cast<int>(it.row()), j, it.value());
        }
    }
    SparseMatrix b(mSetup.model.dofCount(), nj);
    b.setFromTriplets(bt.begin(), bt.end());
    const SparseMatrix kb = stiffness * b;  // fine x J
    Eigen::MatrixXd m = Eigen::MatrixXd(b.transpose() * kb);
    // D = M_JJ - A_JJ; unknowns no secondary node uses are decoupled (kept on A's diagonal).
    Eigen::MatrixXd d = m;
    L.secondaryUnknowns = n;
    for (int j = 0; j < nj; ++j) {
        const int u = L.capJ[sz(j)];
        if (b.col(j).nonZeros() == 0) {
            d(j, j) = mA.coeff(u, u);
            --L.secondaryUnknowns;
        }
        for (SparseMatrix::InnerIterator it(mA, u); it; ++it) {
            const int r = posInJ[sz(static_cast<int>(it.row()))];
            if (r >= 0) d(r, j) -= it.value();
        }
    }
    if (L.secondaryUnknowns == 0) return false;  // no secondary: the empty layout is cheaper
    Eigen::MatrixXd z(nj, nj);
    for (int j = 0; j < nj; ++j)
        for (int i = 0; i < nj; ++i)
            z(i, j) = mW(mZonePos[sz(L.capJ[sz(i)])], mZonePos[sz(L.capJ[sz(j)])]);
    const Eigen::PartialPivLU<Eigen::MatrixXd> lu(Eigen::MatrixXd::Identity(nj, nj) + d * z);
    const Eigen::MatrixXd h = lu.inverse();
    L.capHD = h * d;
    // The border: P dofs coupled to the secondary (rows of K B at P dofs), primary-node order.
    const RowSparseMatrix kbRows = kb;
    std::vector<Triplet> kbt;
    std::vector<std::pair<int, double>> entries;
    L.borderDofs.clear();
    for (int node : L.primaryNodes) {
        for (int k = 0; k < 3; ++k) {
            const int dof = 3 * node + k;
            bool any = false;
            for (RowSparseMatrix::InnerIterator it(kbRows, dof); it; ++it) {
                if (it.value() == 0.0) continue;
                if (!any) {
                    any = true;
                    L.borderDofs.push_back(dof);
                }
                kbt.emplace_back(L.capJ[sz(static_cast<int>(it.col()))],
                                 static_cast<int>(L.borderDofs.size()) - 1, it.value());
            }
        }
    }
    const int nb = static_cast<int>(L.borderDofs.size());
    L.kcb.resize(n, nb);
    L.kcb.setFromTriplets(kbt.begin(), kbt.end());
    if (nb == 0 || L.gammaDofs.empty()) return true;
    // Q = H (-sK K_JB): the secondary's response to the border is A^-1 E_J Q, so at zone unknown
    // u it is W(u, J) Q (Z Q on J itself).
    Eigen::MatrixXd kcbJ = Eigen::MatrixXd::Zero(nj, nb);
    for (const Triplet& t : kbt) kcbJ(posInJ[sz(t.row())], t.col()) = t.value();
    L.capQ = -mSetup.sK * (h * kcbJ);
    InterpBasis basis;
    const bool inside = zoneBasis(
        L.interpGamma.rows(),
        [&](Eigen::Index r, auto&& f) {
            for (RowSparseMatrix::InnerIterator it(L.interpGamma, r); it; ++it)
                f(static_cast<int>(it.col()), it.value());
        },
        L.capJ, mZonePos, mW, basis);
    if (!inside) return false;
    const bool direct = !o.secondaryFullField;
    if (direct) {
        // Gamma's response G = basis Q stays factored (secondaryRegion's solveDirect): rank
        // |J|, where the |Gamma| x |border| product took a third of a layout's build.
        // Watched nodes in the zone: from the zone field per solve (zoneField); outside it,
        // whole-field solves.
        L.watchInZone = L.interpWatch.rows() > 0;
        for (Eigen::Index r = 0; r < L.interpWatch.rows() && L.watchInZone; ++r)
            for (RowSparseMatrix::InnerIterator it(L.interpWatch, r); it; ++it)
                if (mZonePos[sz(static_cast<int>(it.col()))] < 0) L.watchInZone = false;
    }
    // The condensed G = basis Q, kept factored and whole (no entry dropped): G has rank |J|.
    if (direct || o.condensed) {
        L.capZ = Eigen::VectorXd::Zero(nj);
        L.capY = Eigen::VectorXd::Zero(basis.block.rows());
        L.gammaBasis = std::move(basis);
    }
    return true;
}

}  // namespace palp::fem
