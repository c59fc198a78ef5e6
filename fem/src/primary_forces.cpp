// PrimaryRegion: the primary's internal forces by P-node rows (docs/algorithms.md section 6,
// "Primary"): the lattice's unit stencil where a node's eight cells share one modulus, the
// node's cells' rows elsewhere.
#include "index_cast.h"
#include "primary_region.h"

namespace palp::fem {

void PrimaryRegion::buildStencil() noexcept {
    // The lattice's assembled unit stiffness at a node inside eight cells: block (node, node +
    // offset) sums K_e's (a, b) blocks over the cells where the node is corner a and its
    // neighbour corner b (corner bits: x, y, z).
    const std::array<int, 3> nc = mSetup.model.mesh().nodeCounts();
    const Eigen::Map<const Eigen::Matrix<double, 24, 24>, Eigen::Aligned64> Ke(
        mSetup.model.unitStiffness());
    mStencil.fill(0.0);
    for (int q = 0; q < 27; ++q)
        mStencilOffset[sz(q)] = (q % 3 - 1) + nc[0] * ((q / 3) % 3 - 1 + nc[1] * (q / 9 - 1));
    for (int a = 0; a < 8; ++a)
        for (int b = 0; b < 8; ++b) {
            const int q = ((b & 1) - (a & 1) + 1) + 3 * (((b >> 1) & 1) - ((a >> 1) & 1) + 1) +
                          9 * (((b >> 2) & 1) - ((a >> 2) & 1) + 1);
            for (int r = 0; r < 3; ++r)
                for (int col = 0; col < 3; ++col)
                    mStencil[sz(12 * q + 4 * col + r)] += Ke(3 * a + r, 3 * b + col);
        }
}

void PrimaryRegion::internalForces(
    const Layout& L, const double* operand,
    const Eigen::Map<const Eigen::Matrix<double, 24, 24>, Eigen::Aligned64>& K) noexcept {
    // Rows of K u on P nodes (the only rows read): the unit stencil scaled by the modulus
    // where all eight cells are present with one modulus, the node's cells' rows elsewhere.
    for (std::size_t i = 0; i < L.stencilNodes.size(); ++i) {
        const int n = L.stencilNodes[i];
        // Columns padded to 4 rows: whole packets.
        Eigen::Vector4d f = Eigen::Vector4d::Zero();
        for (std::size_t o = 0; o < kStencilPoints; ++o) {
            const double* u = operand + 3 * (n + mStencilOffset[o]);
            const double* s = mStencil.data() + 12 * o;
            f.noalias() += Eigen::Map<const Eigen::Vector4d, Eigen::Aligned16>(s) * u[0];
            f.noalias() += Eigen::Map<const Eigen::Vector4d, Eigen::Aligned16>(s + 4) * u[1];
            f.noalias() += Eigen::Map<const Eigen::Vector4d, Eigen::Aligned16>(s + 8) * u[2];
        }
        mFInt.segment<3>(3 * n) = L.stencilE[i] * f.head<3>();
    }
    for (std::size_t i = 0; i < L.edgeNodes.size(); ++i) {
        Eigen::Vector3d f = Eigen::Vector3d::Zero();
        for (int e = L.edgeCellStart[i]; e < L.edgeCellStart[i + 1]; ++e) {
            const std::array<int, 2>& cell = L.edgeCells[sz(e)];
            const std::array<int, 8>& nd = L.cellDofs[sz(cell[0])];
            Eigen::Matrix<double, 24, 1> ue;
            for (int a = 0; a < 8; ++a) {
                for (int k = 0; k < 3; ++k) ue[3 * a + k] = operand[nd[sz(a)] + k];
            }
            f.noalias() += L.cellE[sz(cell[0])] * (K.middleRows<3>(3 * cell[1]) * ue);
        }
        mFInt.segment<3>(3 * L.edgeNodes[i]) = f;
    }
}

}  // namespace palp::fem
