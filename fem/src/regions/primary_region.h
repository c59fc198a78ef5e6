#pragma once
/// @file
/// PrimaryRegion: the explicit primary region of AsyncRegions (central difference over the
/// primary cells, substepped every servo tick), its coupling to the secondary border Gamma and
/// its force readout.

#include <Eigen/Core>
#include <array>
#include <cstdint>
#include <span>
#include <vector>

#include "palp/fem/coupling_spring.h"
#include "regions/async_layout.h"
#include "regions/async_setup.h"

namespace palp::fem {

/// The servo thread's state of the asynchronous regions: the fine displacement field u (and the
/// previous substep), the coupling state Gamma is interpolated with, the watched nodes'
/// secondary values, and the force drive's loads.
/// @par Threading  Owned by the servo thread (the thread that calls AsyncRegions::tick()); in
/// synchronous mode the period boundary also runs on it. The layouts it is given are read only
/// in their immutable parts. Nothing here is shared with the secondary thread: border values
/// leave through readBorder()/packLoads() into a snapshot, solutions enter through
/// acceptSolution() from a result packet.
/// @par Real-time  Every member but the constructor is noexcept and allocation-free; work
/// vectors are sized to the dof count at construction so that a layout change never allocates.
class PrimaryRegion {
  public:
    /// Sets u to the constraint values (the contact nodes to zero) and the central-difference
    /// coefficients. @p setup must outlive the region.
    PrimaryRegion(const AsyncSetup& setup, const Constraints& constraints,
                  const std::vector<int>& contactNodes);

    /// One tick of substeps driving @p L's contact dofs to @p target at its end; fills
    /// substeps, flags and (displacement drive) the contact reaction in @p result.
    void advance(const Layout& L, const Eigen::Vector3d& target, AsyncTickResult& result) noexcept;
    /// advance() with a coupling @p spring (force drive; may be null or inactive): the spring
    /// force is evaluated at every substep from a(u) (P and Gamma nodes from the current
    /// substep, other nodes as shown at the tick's start), `w_i F` acts on P nodes at that
    /// substep and, averaged over the tick, on the other nodes through the secondary's loads.
    /// The substep honours the spring's frequency on P (the count may change tick to tick; the
    /// half-step velocity is kept). Fills result.spring.
    void advance(const Layout& L, const Eigen::Vector3d& target, const CouplingSpring* spring,
                 AsyncTickResult& result) noexcept;
    /// Force drive: takes this tick's loads (loads on free P dofs act at once, loads on secondary
    /// nodes add to the period's sum); fills contactForce, loadsRefused and flags.
    void takeLoads(const Layout& L, std::span<const NodalLoad> loads,
                   AsyncTickResult& result) noexcept;
    /// Clears this tick's primary loads (after advance()).
    void clearTickLoads() noexcept;
    /// The period's mean load on each secondary dof into @p out; restarts the period's sum.
    /// @p sequence tags the snapshot (its solution's acceptSolution() gives it back): the
    /// spring's mean share on secondary nodes it carries is remembered under it.
    void packLoads(BorderPacket& out, std::uint64_t sequence) noexcept;
    /// The primary border values of @p L (L.borderDofs order) into @p out.
    void readBorder(const Layout& L, double* out) const noexcept;

    /// Takes a secondary solution: Gamma values @p gamma, the border values @p border they
    /// answer, the watched values @p watch (or nullptr), solved from the snapshot packed as
    /// @p sequence; the interpolation restarts from the values shown now.
    void acceptSolution(const Layout& L, const double* gamma, const double* border,
                        const double* watch, std::uint64_t sequence) noexcept;
    /// Gamma as @p L shows it at time @p t into @p target (u or uPrev); with @p product the
    /// condensed correction is recomputed from @p target's border.
    void setGamma(const Layout& L, double* target, double t, bool product) noexcept;
    /// Freezes the border as @p from shows it now (current and previous substep) and the
    /// watched values, before a layout change.
    void showBorder(const Layout& from) noexcept;
    /// Restarts the coupling (Gamma, border, clock) from the values the primary shows now.
    void restartCoupling(const Layout& L) noexcept;
    /// Plain coupling after an adaptive switch: Gamma restarts from the secondary solution
    /// @p x of @p L (coarse unknowns).
    void restartGammaFrom(const Layout& L, const Eigen::VectorXd& x) noexcept;
    /// A layout for a new contact: the shown border, the entry state of @p to, a new coupling.
    void adopt(const Layout& from, const Layout& to) noexcept;
    /// Sets dof @p d to @p value in u and the previous substep (a node entering the primary).
    void enter(int d, double value) noexcept {
        mU[d] = value;
        mUPrev[d] = value;
    }

    /// The displacement of @p node as shown with @p L at the period fraction @p frac (see
    /// AsyncRegions::nodeDisplacement).
    Eigen::Vector3d shown(const Layout& L, int node, double frac) const noexcept;
    /// shown() of every watched node at once (out[i] for watchNodes[i]; out.size() at most
    /// their count): the secondary's interpolated values in one sweep, then the fixed dofs and
    /// the nodes of P and Gamma over them. @par Real-time  O(#watched + |P| + |Gamma|).
    void shownWatched(const Layout& L, double frac, std::span<Eigen::Vector3d> out) const noexcept;
    /// shown() of the watched nodes @p first, @p first + 1, ... into @p out: one pass over the
    /// interpolated values, each node's P / Gamma / fixed state looked up on the way. @return
    /// the count written. @par Real-time  O(out.size()).
    std::size_t shownWatched(const Layout& L, double frac, std::size_t first,
                             std::span<Eigen::Vector3d> out) const noexcept;
    /// AsyncRegions::watchedChanges(): the watched nodes from @p first (at most @p count
    /// examined) whose shown() may differ from @p shown by @p still or more.
    WatchedChanges changedWatched(const Layout& L, double frac, std::size_t first,
                                  std::size_t count, std::span<const double> shown, double still,
                                  std::span<std::uint32_t> index,
                                  std::span<Eigen::Vector3d> out) const noexcept;
    /// The interpolation fraction of the current secondary period.
    double shownFraction() const noexcept { return mSetup.periodFraction(mTime, mGammaStart); }
    /// The watched values' fraction at the coupling fraction @p frac: a layout adopted
    /// mid-period restarts the clock without a new solution, and the part of the way already
    /// shown (mWBase) is kept here instead of being folded into every watched value.
    double watchedFraction(double frac) const noexcept { return mWBase + (1.0 - mWBase) * frac; }

    const Eigen::VectorXd& u() const noexcept { return mU; }
    const Eigen::VectorXd& uPrev() const noexcept { return mUPrev; }
    double time() const noexcept { return mTime; }
    double substepSeconds() const noexcept { return mDtSub; }
    /// Secondary solutions taken up so far.
    std::uint64_t used() const noexcept { return mUsed; }

  private:
    /// Whether Gamma leads from the newest solution (plain coupling, interpolation, plainLead
    /// >= 0) instead of interpolating towards it.
    bool leads() const noexcept {
        return !mSetup.options.condensed && mSetup.options.interpolate &&
               mSetup.options.plainLead >= 0.0;
    }
    void seedWatched(const Layout& from) noexcept;
    /// The lattice's unit stencil (mStencil, mStencilOffset), at construction.
    void buildStencil() noexcept;
    /// mFInt on @p L's P nodes from @p operand (K: the unit element stiffness).
    void internalForces(
        const Layout& L, const double* operand,
        const Eigen::Map<const Eigen::Matrix<double, 24, 24>, Eigen::Aligned64>& K) noexcept;
    /// mFInt on @p nodes (P nodes) from their listed cells' rows of the linear element:
    /// `cells[start[i] .. start[i + 1])` are node i's (index in L.cellDofs, its corner there).
    void cellRows(
        std::span<const int> nodes, std::span<const int> start,
        std::span<const std::array<int, 2>> cells, const Layout& L, const double* operand,
        const Eigen::Map<const Eigen::Matrix<double, 24, 24>, Eigen::Aligned64>& K) noexcept;
    void enterFactored(const Layout& from, const Layout& to) noexcept;
    void setSubstep(const Layout& L, int substeps, double dt) noexcept;
    void addSecondaryLoad(int node, const Eigen::Vector3d& force) noexcept;
    bool shareCompliance(const Layout& L, const CouplingSpring& spring,
                         Eigen::Matrix3d& C) noexcept;

    const AsyncSetup& mSetup;
    double mDtSub = 0.0;
    int mSubsteps = 1;
    int mBaseSubsteps = 1;              // substeps per tick without a spring
    double mBaseDt = 0.0;               // stable substep without a spring, s
    std::uint64_t mCoefGeneration = 0;  // layout whose free dofs have mDtSub's coefficients
    double mTime = 0.0;
    std::uint64_t mUsed = 0;
    Eigen::VectorXd mU, mUPrev, mFInt, mWork, mInvDen, mPrevCoef, mTwoMass, mContactStart;
    // The lattice's unit stencil (internalForces()): 27 3 x 3 blocks, column-major with columns
    // padded to 4 rows, neighbour (dx, dy, dz) at 9 (dz + 1) + 3 (dy + 1) + dx + 1, and the
    // neighbours' node offsets.
    static constexpr std::size_t kStencilPoints = 27;
    alignas(32) std::array<double, 12 * kStencilPoints> mStencil{};
    std::array<int, kStencilPoints> mStencilOffset{};
    bool mStencilAvx2 = false;  // the CPU has AVX2 and FMA (primary_forces.cpp), at construction
    // The unit element stiffness's three rows of each corner a, column-major with columns
    // padded to 4 rows (24 columns a corner): the other P nodes' rows, AVX2 path.
    alignas(32) std::array<double, 8 * 24 * 4> mCornerRows{};
    // Coupling state, sized to the dof count once so that a layout change never allocates;
    // the first |Gamma| / |border| entries are used.
    std::vector<double> mGPrev, mGCur;  // Gamma values the interpolation runs between
    Eigen::VectorXd mBPrev, mBCur;      // primary border values those Gamma values answer
    Eigen::VectorXd mBNow, mGFix;       // condensed coupling work vectors
    Eigen::VectorXd mCapZ;              // factored products: |J| values (twice), see setGamma
    Eigen::VectorXd mCapY;              // and the zone block's |T| values (twice), interp_basis.h
    Eigen::VectorXd mEntryWork;         // adopt(): the entry values at the previous substep
    double mGammaStart = 0.0;           // coupling clock: time the interpolation started
    // Watched secondary values the interpolation runs between (3 per watched node).
    std::vector<double> mWPrev, mWCur;
    // The fraction of the way from mWPrev to mWCur shown when the clock last restarted without
    // a solution (seedWatched()); 0 once a solution arrives.
    double mWBase = 0.0;
    // Force drive: loads on free primary dofs this tick, and the sum over the current period of
    // the loads on secondary nodes.
    Eigen::VectorXd mFExt, mFAcc;
    std::vector<int> mFExtDofs;  // capacity 3 * maxLoads
    std::size_t mFExtCount = 0;
    std::vector<int> mAccNodes;  // nodes with a non-zero mFAcc entry, capacity #nodes
    std::size_t mAccCount = 0;
    std::vector<std::uint8_t> mAccMark;  // per node
    // The spring's share on secondary nodes, condensed (see advance()): its compliance's work
    // space (per axis: zone positions and weights of the share's coarse support; W_(J, g)),
    // the period's sum of the share force, and the share force each snapshot carried and the
    // shown secondary values answer (interpolated like them).
    static constexpr std::size_t kShareEntries = 1024;  // per axis
    std::array<std::vector<int>, 3> mSharePos;
    std::array<std::vector<double>, 3> mShareWeight;
    std::array<std::size_t, 3> mShareCount{};
    std::vector<int> mShareSlot;  // per zone position: its entry, or -1 (all -1 between calls)
    Eigen::MatrixXd mShareV;      // |J| x 3
    Eigen::MatrixXd mShareHDV;    // |J| x 3
    Eigen::Vector3d mShareAcc = Eigen::Vector3d::Zero();
    Eigen::Vector3d mSharePrev = Eigen::Vector3d::Zero(), mShareCur = Eigen::Vector3d::Zero();
    std::array<std::uint64_t, 8> mShareSeq{};
    std::array<Eigen::Vector3d, 8> mShareSent{};
    std::size_t mShareNext = 0;
    // The last tick's condensed share (layout it was computed on, F - F~ at its end) and a
    // work vector: nodes the next layout shows take the share's correction at a swap.
    bool mShareLive = false;
    Eigen::Vector3d mShareDelta = Eigen::Vector3d::Zero();
    Eigen::VectorXd mShareH;
    void applyShareCorrection(const Layout& from, const Layout& to) noexcept;
};

}  // namespace palp::fem
