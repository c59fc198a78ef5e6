// PrimaryRegion: the coupling spring's share on secondary nodes, condensed (issue 18,
// docs/algorithms.md "Swaps and a finger off its primary"): its compliance from the capacitance
// zone block, and the correction the nodes a new layout shows take at a swap.
#include <algorithm>

#include "index_cast.h"
#include "regions/async_capacitance.h"
#include "regions/primary_region.h"

namespace palp::fem {

bool PrimaryRegion::shareCompliance(const Layout& L, const CouplingSpring& spring,
                                    Eigen::Matrix3d& C) noexcept {
    // C = w_S^T I M^-1 I^T w_S per axis pair: the secondary's compliance at the spring's
    // nodes outside P (M: the layout's secondary, (M^-1)_TT = W_TT - W_TJ H D W_JT on the
    // capacitance zone). false: nothing outside P, or a node outside the zone.
    if (L.global == nullptr) return false;
    const GlobalSecondary& g = *L.global;
    const RowSparseMatrix& I = g.interpolation();
    const Eigen::MatrixXd& W = g.zoneInverse();
    const HexMesh& mesh = mSetup.model.mesh();
    mShareCount = {0, 0, 0};
    // Entries on one zone position (a coarse dof several of the spring's nodes interpolate
    // from) are merged, so the double sums below run over distinct coarse dofs.
    auto clearSlots = [&] {
        for (std::size_t a = 0; a < 3; ++a)
            for (std::size_t e = 0; e < mShareCount[a]; ++e) mShareSlot[sz(mSharePos[a][e])] = -1;
    };
    bool outside = false;
    for (std::size_t i = 0; i < spring.nodes.size(); ++i) {
        const int n = spring.nodes[i];
        const double w = spring.weights[i];
        if (n < 0 || n >= mesh.nodeCount() || !mesh.nodeActive()[sz(n)] || L.isPrimary[sz(n)] ||
            !(w > 0.0))
            continue;
        outside = true;
        for (std::size_t a = 0; a < 3; ++a) {
            const int d = 3 * n + static_cast<int>(a);
            if (mSetup.fixed[sz(d)]) continue;
            for (RowSparseMatrix::InnerIterator it(I, d); it; ++it) {
                const int p = g.zonePosition(static_cast<int>(it.col()));
                if (p < 0 || sz(p) >= mShareSlot.size() || mShareCount[a] >= kShareEntries) {
                    clearSlots();
                    return false;
                }
                if (mShareSlot[sz(p)] >= 0) {
                    mShareWeight[a][sz(mShareSlot[sz(p)])] += w * it.value();
                    continue;
                }
                mShareSlot[sz(p)] = static_cast<int>(mShareCount[a]);
                mSharePos[a][mShareCount[a]] = p;
                mShareWeight[a][mShareCount[a]] = w * it.value();
                ++mShareCount[a];
            }
        }
    }
    clearSlots();
    if (!outside) return false;
    const Eigen::Index nj = static_cast<Eigen::Index>(L.capJ.size());
    if (nj > mShareV.rows() || L.capHD.rows() != nj || L.capHD.cols() != nj) return false;
    for (std::size_t a = 0; a < 3; ++a) {
        for (std::size_t b = 0; b < 3; ++b) {
            double s = 0.0;
            for (std::size_t e = 0; e < mShareCount[a]; ++e)
                for (std::size_t f = 0; f < mShareCount[b]; ++f)
                    s += mShareWeight[a][e] * mShareWeight[b][f] *
                         W(mSharePos[a][e], mSharePos[b][f]);
            C(static_cast<Eigen::Index>(a), static_cast<Eigen::Index>(b)) = s;
        }
        for (Eigen::Index j = 0; j < nj; ++j) {
            const int pj = g.zonePosition(L.capJ[sz(static_cast<int>(j))]);
            double v = 0.0;
            for (std::size_t e = 0; e < mShareCount[a]; ++e)
                v += mShareWeight[a][e] * W(mSharePos[a][e], pj);
            mShareV(j, static_cast<Eigen::Index>(a)) = v;
        }
    }
    // C -= V^T (H D) V, as loops (no temporaries on the servo).
    for (Eigen::Index r = 0; r < nj; ++r) {
        double s0 = 0.0, s1 = 0.0, s2 = 0.0;
        for (Eigen::Index j = 0; j < nj; ++j) {
            const double h = L.capHD(r, j);
            s0 += h * mShareV(j, 0);
            s1 += h * mShareV(j, 1);
            s2 += h * mShareV(j, 2);
        }
        mShareHDV(r, 0) = s0;
        mShareHDV(r, 1) = s1;
        mShareHDV(r, 2) = s2;
    }
    for (Eigen::Index a = 0; a < 3; ++a)
        for (Eigen::Index b = 0; b < 3; ++b) {
            double s = 0.0;
            for (Eigen::Index j = 0; j < nj; ++j) s += mShareV(j, a) * mShareHDV(j, b);
            C(a, b) -= s;
        }
    return C.allFinite();
}

void PrimaryRegion::applyShareCorrection(const Layout& from, const Layout& to) noexcept {
    // The condensed spring share (advance()) held the spring's nodes outside P at the shown
    // field plus C (F - F~); the nodes the new layout shows that the old one did not integrate
    // take that correction, (M^-1 I_S^T w_S (F - F~))_d, so the swap does not jump the spring.
    // With c the share's load on the zone less its capacitance part, the correction is I (W c)
    // at those dofs: the prepared rows I W(T, J) (to.shareBasis) give W c's J part, and the
    // share's own columns of W, read at T, the rest.
    if (!mShareLive || from.global == nullptr) return;
    mShareLive = false;
    const InterpBasis& B = to.shareBasis;
    const Eigen::Index nj = static_cast<Eigen::Index>(from.capJ.size());
    const Eigen::Index t = B.block.rows();
    if (!B.fits(static_cast<Eigen::Index>(to.shareDofs.size()), nj) || 2 * t > mCapY.size() ||
        nj > mShareH.size())
        return;
    const Eigen::MatrixXd& W = from.global->zoneInverse();
    for (Eigen::Index j = 0; j < nj; ++j) mShareH[j] = mShareHDV.row(j).dot(mShareDelta);
    // y = -(W c) at T, the J part first.
    auto y = mCapY.head(t);
    y.noalias() = B.block * mShareH.head(nj);
    for (std::size_t b = 0; b < 3; ++b) {
        const double db = mShareDelta[static_cast<Eigen::Index>(b)];
        for (std::size_t f = 0; f < mShareCount[b]; ++f) {
            // W is symmetric: its column at the share's position, read at T.
            const double* col = W.col(mSharePos[b][f]).data();
            const double c = mShareWeight[b][f] * db;
            for (Eigen::Index i = 0; i < t; ++i) y[i] -= c * col[B.pos[sz(static_cast<int>(i))]];
        }
    }
    double* delta = mCapY.data() + t;
    B.interpolate(y.data(), delta);
    for (std::size_t i = 0; i < to.shareDofs.size(); ++i) {
        const int d = to.shareDofs[i];
        mU[d] -= delta[i];
        mUPrev[d] -= delta[i];
    }
}

}  // namespace palp::fem
