#pragma once
/// @file
/// The data of the asynchronous regions that the primary, the secondary and the layout builder
/// share: one arrangement of the regions with its secondary system (Layout), and the border data
/// that crosses between the servo and the secondary (BorderPacket).

#include <Eigen/CholmodSupport>
#include <Eigen/Core>
#include <Eigen/SparseCore>
#include <array>
#include <cstdint>
#include <vector>

#include "palp/base/nothrow_slot.h"
#include "palp/base/triple_buffer.h"
#include "palp/fem/fem_model.h"
#include "regions/interp_basis.h"
#include "solvers/pcg.h"

namespace palp::fem {

class GlobalSecondary;

/// Border data crossing threads, preallocated to the dof count (Gamma and the primary border are
/// disjoint sets of dofs, so both fit; results also carry 3 values per watched node).
struct BorderPacket {
    /// Snapshots: the primary border values. Results: Gamma, then the border they answer, then
    /// the watched nodes' values.
    std::vector<double> values;
    // Snapshots, force drive: period-averaged loads on secondary dofs (fine dof, newtons).
    std::vector<int> loadDofs;
    std::vector<double> loadValues;
    int loadCount = 0;
    double time = 0.0;
    std::uint64_t sequence = 0;
    std::uint64_t generation = 0;  // layout the values belong to
};

/// The two lock-free exchanges between the servo and the secondary thread (threaded mode):
/// snapshots of the primary border (servo writes, secondary reads) and secondary solutions
/// (secondary writes, servo reads). Synchronous mode uses their back slots as work buffers.
/// @par Threading  Each buffer has one writer and one reader thread (acquire/release exchange of
/// the slot index, palp::TripleBuffer); the slots are sized once at construction.
struct BorderExchange {
    using Buffer = TripleBuffer<NothrowSlot<BorderPacket>>;
    /// Sizes every slot for @p dofs dofs and @p watchValues watched values.
    BorderExchange(int dofs, std::size_t watchValues)
        : snapshots(NothrowSlot<BorderPacket>(snapshotPacket(dofs))),
          results(NothrowSlot<BorderPacket>(resultPacket(dofs, watchValues))) {}
    Buffer snapshots;  ///< servo -> secondary
    Buffer results;    ///< secondary -> servo

  private:
    static BorderPacket snapshotPacket(int dofs) {
        BorderPacket p;
        p.values.assign(static_cast<std::size_t>(dofs), 0.0);
        p.loadDofs.assign(static_cast<std::size_t>(dofs), 0);
        p.loadValues.assign(static_cast<std::size_t>(dofs), 0.0);
        return p;
    }
    static BorderPacket resultPacket(int dofs, std::size_t watchValues) {
        BorderPacket p;
        p.values.assign(static_cast<std::size_t>(dofs) + watchValues, 0.0);
        return p;
    }
};

/// One arrangement of the regions with its secondary system.
/// @par Threading  Built and factorised by LayoutBuilder (constructor, builder thread or the
/// synchronous period boundary), then immutable except for the secondary's work state below
/// (x .. border, fieldStale: the secondary's thread only) and the entry state (written by the
/// preparing thread before the layout is published to the servo with a release store).
struct Layout {
    int seeds = 0;
    std::uint64_t generation = 0;                // unique per prepared layout
    std::vector<int> contactNodes, contactDofs;  // driven nodes (always in P)
    // State handed to the primary at a contact change: fine dofs of P and Gamma that were
    // secondary interior before, with the secondary's latest values there.
    std::vector<int> entryDofs;
    std::vector<double> entryValues;
    // The entry values' linear response to the border of the layout they leave (|entryDofs| x
    // |from.borderDofs|, empty where unknown) and the border they answer: the servo moves them
    // to the border it shows at the swap, `value + E (u_B - entryBorder)` (a quasi-static
    // field is linear in its border; values a period old made each swap a kick, issue 18).
    Eigen::MatrixXd entryResponse;
    Eigen::VectorXd entryBorder;
    // Capacitance layouts: the same response factored, E = entryBasis entryQ (|entryDofs| x
    // |J|, itself kept as interpolation times zone block, and from's capQ, |J| x
    // |from.borderDofs|; entryResponse then empty): the swap's product has inner size |J|
    // (~50-100) instead of |border| (hundreds).
    InterpBasis entryBasis;
    Eigen::MatrixXd entryQ;
    // Capacitance layouts: the free dofs of the nodes of P and Gamma that the layout left
    // (from) did not integrate, and `I W(., from's J)` there (factored, T its zone positions):
    // the spring share's correction at the swap, `I (W_(., share) - W_(., J) H D V) (F - F~)`,
    // needs only these rows and the share's columns of W (primary_share.cpp).
    std::vector<int> shareDofs;
    InterpBasis shareBasis;
    std::vector<int> primaryNodes;             // P, sorted
    std::vector<std::uint8_t> isPrimary;       // per fine node
    std::vector<std::array<int, 8>> cellDofs;  // 3 * node of the 8 nodes of each primary cell
    std::vector<double> cellE;                 // Young's modulus per primary cell
    std::vector<int> touchedDofs;              // dofs of all nodes of primary cells
    // A neo-Hookean model's primary: TLED on the cells whose eight nodes are all in P (their
    // dofs and moduli), the linear element on the others (the seam), which share Gamma nodes
    // with the secondary: the forces across the border are the linear element's on both sides
    // (the secondary sees those cells linear too), so nothing is created there. The seam's
    // rows on P nodes as edgeNodes' (the P nodes with a seam cell, and their seam cells).
    std::vector<std::array<int, 8>> tledCellDofs;
    std::vector<double> tledCellE;
    std::vector<int> seamNodes;
    std::vector<int> seamCellStart;
    std::vector<std::array<int, 2>> seamCells;
    // The primary's internal forces row by row on P nodes (the only rows read): a node whose
    // eight cells are all present with one modulus takes the lattice's assembled unit stencil
    // (27 3x3 blocks, 243 multiply-adds), the others (surface, inclusions) their cells' rows
    // (72 a cell). The cell loop it replaces spent 576 a primary cell, Gamma rows included.
    std::vector<int> stencilNodes;
    std::vector<double> stencilE;
    std::vector<int> edgeNodes;                 // the other P nodes
    std::vector<int> edgeCellStart;             // edgeNodes[i]'s cells: [start[i], start[i + 1])
    std::vector<std::array<int, 2>> edgeCells;  // (index in cellDofs, the node's corner there)
    std::vector<int> freeDofs;                  // free P dofs the primary integrates
    std::vector<int> gammaNodes, gammaDofs;     // secondary border: free S dofs of primary cells
    std::vector<std::uint8_t> isGamma;          // per fine node
    std::vector<int> borderDofs;                // P dofs coupled to the secondary
    int freeNodeCount = 0;
    // Secondary (coarse unknowns).
    std::vector<int> unknownCoarseDof;  // unknown -> coarse dof
    RowSparseMatrix interp;             // fine dofs x unknowns (rows of P / fixed dofs empty)
    RowSparseMatrix interpGamma;        // gamma dofs x unknowns
    RowSparseMatrix interpWatch;        // 3 * #watched x unknowns (rows of interp)
    SparseMatrix kc, mc;                // unknowns x unknowns
    RowSparseMatrix kcb;                // unknowns x border dofs
    Eigen::CholmodSupernodalLLT<SparseMatrix, Eigen::Lower> cholmod;
    RowSparseMatrix rowA;  // PCG secondary: the system matrix
    Eigen::VectorXd inverseDiagonal;
    // G: gamma dofs x border dofs (condensed coupling), small entries dropped.
    RowSparseMatrix response;
    // Capacitance secondary: Gamma's response to the border, factored: G = gammaBasis capQ
    // exactly (gammaBasis = I_Gamma W(., J), |Gamma| x |J|, itself kept as Gamma's
    // interpolation times the zone block W(T, J), interp_basis.h; response and gammaResponse
    // then empty). G has rank |J| (the primary coarse cells' corners, ~50-100 dofs) but
    // |Gamma| x |border| entries (~620,000 on the bone phantom's 2.5 mm body): the servo's
    // condensed correction and the secondary's direct solve are products through |J| values
    // (capZ, capY: the secondary's work vectors, |J| and |T|).
    InterpBasis gammaBasis;
    Eigen::VectorXd capZ, capY;
    // Quasi-static CHOLMOD secondary: the exact Gamma response to the border (dense), so that a
    // secondary solve needs only Gamma = R u_B; the whole field x is solved when asked for.
    Eigen::MatrixXd gammaResponse;
    Eigen::MatrixXd watchResponse;  // the same for the watched dofs (3 * #watched x border)
    bool fieldStale = false;        // x (and uC) lag the last border (direct Gamma solves)
    // Capacitance secondary (async_capacitance.h): the whole body's factor and this layout's
    // update. null: the layout's own factorisation (cholmod above) or PCG.
    const GlobalSecondary* global = nullptr;
    std::vector<int> primaryCoarseCells;  // coarse cells of the primary (coarse cell index)
    std::vector<int> capJ;                // J: unknowns at the primary coarse cells' corners
    int secondaryUnknowns = 0;            // unknowns a secondary node uses (the rest decoupled)
    Eigen::MatrixXd capHD;                // H D (|J| x |J|), M^-1 b = y - A^-1 E_J H D y_J
    Eigen::MatrixXd capQ;                 // H (-sK K_JB): the field is A^-1 E_J capQ u_B
    // Capacitance secondary under loads on zone dofs (GlobalSecondary::loadResponse): the
    // loads' part of the field on the zone (zone positions) and their restriction I_S^T f
    // (unknowns) from the last solve; `loaded` false: no such part (none, or x holds it).
    Eigen::VectorXd loadZone, loadRhs;
    bool loaded = false;
    // Capacitance secondary whose watched nodes interpolate from the zone: their values come
    // from the zone field per solve (GlobalSecondary::zoneField into zoneWork) instead of a
    // dense watchResponse per layout (3 #watched x |border|: tens of ms per layout for a
    // watched face, where the zone field is ~0.2 ms per solve).
    bool watchInZone = false;
    Eigen::VectorXd zoneWork;
    // Secondary work vectors (secondary thread only).
    Eigen::VectorXd x, v, a, rhs, xNew, yc, ym, border;
    PcgWorkspace pcg;
};

/// f(dof) for every free dof of the nodes of @p to's P and Gamma that @p from showed from its
/// secondary (interior secondary nodes). Allocates.
template <class F>
void forEachEnteringDofIndex(const Layout& from, const Layout& to,
                             const std::vector<std::uint8_t>& fixed, F&& f) {
    std::vector<std::uint8_t> known(from.isPrimary);
    for (int n : from.gammaNodes) known[static_cast<std::size_t>(n)] = 1;
    auto enter = [&](int n) {
        if (known[static_cast<std::size_t>(n)]) return;
        known[static_cast<std::size_t>(n)] = 1;
        for (int k = 0; k < 3; ++k) {
            const int d = 3 * n + k;
            if (!fixed[static_cast<std::size_t>(d)]) f(d);
        }
    };
    for (int n : to.primaryNodes) enter(n);
    for (int n : to.gammaNodes) enter(n);
}

/// f(dof, value) for every free dof of the nodes of @p to's P and Gamma that @p from showed from
/// its secondary (interior secondary nodes): value = @p from's latest secondary solution there.
/// Reads @p from's secondary state: call it on the secondary's thread. Allocates.
template <class F>
void forEachEnteringDof(const Layout& from, const Layout& to,
                        const std::vector<std::uint8_t>& fixed, F&& f) {
    forEachEnteringDofIndex(from, to, fixed, [&](int d) {
        f(d, from.unknownCoarseDof.empty() ? 0.0 : from.interp.row(d).dot(from.x));
    });
}

}  // namespace palp::fem
