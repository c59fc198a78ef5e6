#pragma once
/// @file
/// AsyncRegions: asynchronous FEM regions (docs/algorithms.md section 6, thesis paper I). A small
/// primary region around the contact is integrated explicitly every servo tick; the rest of the
/// body (the secondary region) is solved implicitly at a lower rate, optionally on a coarser
/// grid, on its own thread.
///
/// Regions. The N nodes nearest the contact node(s) in graph distance (lattice edges between
/// active nodes, ties broken by Euclidean distance) seed the primary. Primary cells are the cells
/// touching a seed; with level of detail L > 1 they are widened to whole coarse cells (L^3 fine
/// cells) so that the secondary is exactly a set of coarse cells. The primary nodes P are the
/// nodes all of whose active cells are primary (so P contains the seeds, and every cell touching
/// P is primary); every other node is secondary (S). The secondary border (Gamma) is the free
/// S nodes of primary cells; the primary border is the P nodes coupled to S.
///
/// Primary: central difference (same scheme as ExplicitSolver, substepped below the stable step)
/// over the primary cells only; Gamma follows `u~_S(t)`, linear in time from the displayed value
/// to the newest secondary solution over one secondary period (or the newest solution at once
/// when interpolation is off: the "moving wall"). With the plain coupling Gamma instead starts at
/// the newest solution and moves on along its last change (plainLead): the interpolation lags a
/// whole period and diverged at 500 Hz.
///
/// With `condensed` (the default, beyond the thesis) Gamma additionally follows the secondary's
/// linear response to the primary border's motion since the last solve, so the stiff part of the
/// coupling acts without delay; in the quasi-static limit this is the condensed (Schur) system.
///
/// Secondary: quasi-static by default (or Newmark, or backward Euler, with dt = one period; the
/// dynamic ones only with the plain coupling at low rates) in the Galerkin coarse space
/// `u_S = I u_c` (I: trilinear fine-from-coarse interpolation on the secondary coarse cells, the
/// identity for L = 1): `I^T A_SS I u_c = I^T (b_S - K_SP u_P)`. Coupling forces are thus
/// restricted with the transpose of the interpolation; for L = 1 this is exactly
/// `A_SS u_S = b_S - K_SP u_P`. Solved with CHOLMOD (factorised once per layout) or warm-started
/// Jacobi PCG parallelised with TBB.
///
/// Contact changes (re-allocation). requestContactNode() asks for a new contact node; a layout
/// for it (regions, primary operator, secondary factorisation, condensed response, and the
/// secondary's latest values on the nodes that enter the primary or its border) is prepared off
/// the servo path: on a builder thread in threaded mode (while the secondary keeps solving),
/// inline at the next secondary period boundary in synchronous mode. The servo tick adopts a
/// prepared layout with one pointer exchange and an O(|P| + |Gamma|) state hand-over, so it
/// never waits; until then the old contact stays driven. At the swap the old contact node is
/// released with its current displacement and velocity, the new one moves from its current
/// displacement to the tick's target within that tick, and the coupling restarts from the
/// values the primary shows (no jump in Gamma). Nodes that enter P or Gamma take the secondary
/// field at the border shown at the swap (the solution's values moved by their response to the
/// border since that solve; quasi-static CHOLMOD secondaries), not a period-old one. Only
/// single-node contacts move; the seed count is kept; a contact that cannot be prepared (e.g. a
/// non-zero prescribed value would fall in the secondary) is ignored until another node is
/// requested.
///
/// Sliding contact (issue 18). A layout used to cost an assembly and a CHOLMOD factorisation of
/// its secondary plus its responses: 2-4.5 s at 33^3 lod 2, so a contact sliding a node every
/// 100 ms was almost never followed. With the quasi-static CHOLMOD secondary (globalSecondary,
/// the default) the whole body's Galerkin system A is factorised ONCE; a layout's secondary
/// differs from it only on J, the coarse dofs at the corners of its primary coarse cells, and
/// is reached through the capacitance (Woodbury) identity from `Z = (A^-1)_JJ` and a local
/// |J| x |J| correction (async_capacitance.h, exact to rounding). Z comes from a dense block
/// of A^-1 over a zone of coarse dofs that holds J for every slide node (slideNodes, by default
/// the bounding-box face of the contact), taken from the factor once at set-up by ordering the
/// zone last. A layout then costs ~10-20 ms of one core (regions, gathers, |J|^3 dense work;
/// |J| ~ 50-300), and the secondary thread prefetches the layouts of the contact's slide
/// neighbours, so a request for one is adopted at the next tick (its entry state comes from
/// the zone block too, without a solve). A contact that slides faster than a node per build (a 100
/// mm/s raster on 2.5 mm cells: a node every 25 ms, builds of 40-350 ms on a loaded core) is
/// followed too: a build the contact has overtaken is still adopted when it is nearer the contact
/// than the layout in use, and a build aims where the contact will be when it is done (the
/// requests' velocity over the last 150 ms times the recent build time, on a slide node); before,
/// each such build was shelved and a raster adopted 3 layouts in 6 s. Other secondaries, contacts
/// off the slide nodes and zones over slideZoneMaxDofs build and factorise per layout as before. A
/// solve of the whole secondary field costs two solves with the global factor.
///
/// Why this design: the alternatives in the issue cost more per move. Factorising the layout
/// (even reusing the symbolic analysis) is ~2 s; CHOLMOD update/downdate of the primary's rows
/// is a rank ~2|J| modification of a supernodal factor; solving A for J's columns per layout is
/// ~9 ms a column with the reference BLAS (|J| columns: 0.5-2 s); a fixed partition of windows
/// needs one factorisation per window. The zone block costs memory (8 |T|^2 bytes: 24 MB for
/// the top 2 coarse layers of 33^3 at lod 2) and seconds at set-up, once.
///
/// Drives. `ContactDrive::displacement` (the thesis's input): the contact nodes are driven by a
/// prescribed displacement and tick(const Eigen::Vector3d&) returns their reaction.
/// `ContactDrive::force` (virtual coupling on deformable tissue): every node is free and
/// tick(std::span<const NodalLoad>) takes external nodal loads for that tick (at most
/// maxLoads; extra ones are refused with kAsyncLoadsRefused). Loads on free primary dofs enter
/// the primary's central-difference update at once. Loads on secondary nodes (Gamma included)
/// are averaged over the secondary period (sum over the period's ticks / its tick count: the
/// period's impulse, so a load acting between solves still counts) and enter the secondary's
/// right-hand side restricted with I^T: `I^T A_SS I u_c = I^T (f_S - K_SP u_P)`. They act one
/// to two periods late (the staggered delay). Not conserved exactly: in threaded mode a
/// period's secondary loads are dropped when the secondary has not read that period's snapshot
/// before the next one replaces it (a solve longer than a period) or when a layout change
/// discards it; and loads gathered on nodes that enter the primary at a layout change are
/// dropped for that period. The dropped share is one period's impulse on those nodes. The region
/// centre stays the contact node(s): move it with requestContactNode() when the load moves. A
/// secondary solve with loads solves the whole secondary field (two triangular solves, see
/// secondaryFullField), except on the capacitance secondary when every loaded node interpolates
/// from the zone (a contact's filtered load on the slide face): the loads' part of Gamma and
/// of the watched nodes then comes from the zone block, `W b - W_TJ H D (W b)_J` (exact, ~0.1
/// ms at 33^3 lod 2 against ~15-60 ms for the two solves, which had starved a sliding contact's
/// layout builds on the shared core; GlobalSecondary::loadResponse).
///
/// Watched nodes. `watchNodes` (fixed at construction) are nodes whose displacement the servo
/// needs every tick without displacement() (a deformable body's surface). Each secondary solve
/// also publishes the watched nodes' values from its field; nodeDisplacement() /
/// watchedDisplacements() give the primary's values on P and Gamma and the time-interpolated
/// secondary values elsewhere, allocation- and lock-free. Cost: with the direct quasi-static
/// CHOLMOD secondary (secondaryFullField = false) the watched values come, like Gamma, from a
/// dense response to the border taken at set-up (3 #watched x |border| doubles per layout, as
/// many multiply-adds per solve; the capacitance secondary adds loads on zone nodes from its
/// zone block); a solve with other loads on secondary nodes, watched nodes outside the zone,
/// and the other secondaries, solve the whole field (two triangular solves: ~14 ms CPU at 33^3
/// lod 2 with the top face watched, against 0.2-0.5 ms for the direct responses; bench_async
/// force).
/// Stability: the quasi-static secondary removes the far field's inertia, so a loop that feeds
/// the displacement back into the loads (virtual coupling) sees about the static compliance of
/// the body; see haptics/deformable.h.
///
/// Modes. Synchronous (deterministic, for accuracy tests and tables): the secondary is solved
/// inline at the end of every secondary period of simulated time and used from the next tick.
/// Threaded: the secondary runs on a std::thread inside a tbb::task_arena; border data crosses
/// through lock-free triple buffers; the primary uses a solution from the tick it arrives at and
/// otherwise keeps running on the last good data (a stalled secondary never blocks a tick).
///
/// Adaptive primary size (synchronous mode): the seed count grows
/// linearly with the contact strain `|u_contact| / strainReferenceLength` from primaryNodes to
/// maxPrimaryNodes, quantised to adaptiveLevels layouts prepared at construction; a layout change
/// happens at a secondary period boundary and transfers the state (new primary nodes take the
/// secondary's solution, new secondary nodes the primary's). With the condensed coupling Gamma
/// restarts from the values shown at the switch, consistent with the shown border (restarting
/// it from the secondary's last solution, which answers an older border, made the correction
/// G (u_B - u~_B) inconsistent and excited growing oscillations); the condensed coupling is
/// already within ~0.2 % with a small fixed primary, so adaptivity helps mainly the plain one.
///
/// @par Threading  One thread (the servo thread) calls tick() and the accessors; the model and
/// constraints must outlive the object. In threaded mode the object owns one extra thread, which
/// is joined by the destructor, plus, while a contact change is being prepared (or, once the
/// contact has moved, a slide neighbour's layout prefetched), a builder thread started by it
/// (same CPU and priority) that only reads the immutable model data. Threaded mode: the
/// servo thread owns the primary state, the secondary thread the secondary state; they share only
/// the two triple buffers (acquire/release index exchange) and atomic counters.

#include <Eigen/Core>
#include <cstdint>
#include <memory>
#include <span>
#include <vector>

#include "palp/fem/constraints.h"
#include "palp/fem/coupling_spring.h"
#include "palp/fem/fem_model.h"
#include "palp/fem/implicit_solver.h"
#include "palp/fem/tled.h"

namespace palp::fem {

/// What drives the contact (see "Drives" above).
enum class ContactDrive {
    displacement,  ///< contact nodes follow a prescribed displacement; the result is their reaction
    force,         ///< all nodes free; external nodal loads each tick
};

/// An external load on one node for one tick (force drive).
struct NodalLoad {
    int node = -1;                                    ///< fine node index
    Eigen::Vector3d force = Eigen::Vector3d::Zero();  ///< newtons, world frame
};

/// Flag of tick(): loads beyond maxLoads, on inactive or out-of-range nodes, or with non-finite
/// components were refused (the tick ran with the others). Outside the StepFlag bits.
constexpr unsigned kAsyncLoadsRefused = 1u << 12;
/// Flag of tick(), threaded mode: no secondary solution has entered for more than
/// kAsyncSecondaryStaleSeconds of ticks (a secondary thread stalled, dead, or far behind): the
/// primary runs on the last border data it has, which keeps its force finite and bounded; the
/// next solution clears it.
constexpr unsigned kAsyncSecondaryStale = 1u << 13;
/// Ticks' time without a secondary solution after which tick() flags kAsyncSecondaryStale, s.
constexpr double kAsyncSecondaryStaleSeconds = 0.5;

/// Options of AsyncRegions.
struct AsyncRegionsOptions {
    ContactDrive drive = ContactDrive::displacement;  ///< prescribed displacement or nodal loads
    int maxLoads = 64;  ///< force drive: capacity of tick()'s load list (>= 1)
    /// Nodes whose displacement nodeDisplacement()/watchedDisplacements() give every tick
    /// (distinct active nodes; e.g. a deformable body's surface nodes). Non-empty: every
    /// secondary solve solves the whole field (see "Watched nodes").
    std::vector<int> watchNodes;
    double tickSeconds = 1e-3;    ///< servo period, seconds (> 0)
    double secondaryRate = 50.0;  ///< f_s, Hz: period = max(1, round(1 / (f_s tick))) ticks
    int primaryNodes = 30;        ///< N seeds of the primary region (>= contact node count)
    int lod = 1;                  ///< secondary level of detail: 1, 2 or 4 (times h)
    bool interpolate = true;      ///< interpolate the secondary border in time
    /// Plain coupling with interpolate: how Gamma moves over a secondary period. >= 0: from the
    /// newest solution G_k on along its last change, `u_Gamma = G_k + plainLead s (G_k - G_k-1)`
    /// (s the period fraction; 0 is the moving wall): on bench_async's cube stable at N 5 and 30,
    /// 10-500 Hz, with the quasi-static and backward-Euler secondaries (Newmark stays unstable).
    /// Negative: the thesis's interpolation from the value shown to G_k, a whole period late,
    /// which diverged at 500 Hz with N 30 (docs/algorithms.md, "Stability of the staggered
    /// coupling"). Must be <= 1.
    double plainLead = 0.5;
    /// Condensed (Schur/Norton) coupling: Gamma also follows the secondary's instantaneous linear
    /// response `G = -I_Gamma A^-1 sK K_SB` to the primary border's motion since the solution it
    /// shows (`u_Gamma = u~_Gamma + G (u_B - u~_B)`). Off: the thesis's plain staggered coupling
    /// (see plainLead; its stability analysis: palp/fem/async_stability.h).
    bool condensed = true;
    /// Entries of G below this fraction of its largest are dropped (layouts with their own
    /// factorisation; the capacitance secondary keeps G whole, as the rank-|J| product
    /// `I_Gamma W(., J) Q`).
    double condensedDropTolerance = 1e-3;
    /// Apply G once per tick (at the first substep; later substeps reuse that correction)
    /// instead of at every substep: cheaper for large borders with several substeps.
    bool condensedOncePerTick = false;
    /// Default quasi-static: the far field's inertia is small in the haptic band, and Newmark
    /// combined with the condensed coupling is unstable (bench/README.md); Newmark works with
    /// the plain coupling at low rates.
    Integrator secondaryIntegrator = Integrator::quasiStatic;
    LinearSolverKind secondarySolver = LinearSolverKind::cholmod;  ///< cholmod or pcg
    /// Quasi-static CHOLMOD secondary: false (default) solves only Gamma per secondary solve,
    /// `u_Gamma = R u_B` with the exact response R = -I_Gamma A^-1 K_SB taken from the
    /// factorisation at set-up (|Gamma| x |border| multiply-adds); the whole secondary field is
    /// then solved (two triangular solves) only when it is needed (displacement(), a layout
    /// change). true: the two triangular solves at every secondary solve.
    bool secondaryFullField = false;
    /// Quasi-static CHOLMOD secondary: factorise the whole body's secondary system once and give
    /// each contact's layout its secondary through the capacitance update over the primary
    /// (see "Sliding contact"); false: assemble and factorise every layout (seconds each).
    bool globalSecondary = true;
    /// Fine nodes the contact may move to without a factorisation (globalSecondary). Empty: the
    /// active nodes of the bounding-box face the contact node(s) lie on (none: every layout is
    /// factorised). The zone of coarse dofs these contacts' primaries can reach is inverted
    /// densely at set-up; a zone of more than slideZoneMaxDofs dofs turns globalSecondary off.
    std::vector<int> slideNodes;
    int slideZoneMaxDofs = 3000;         ///< cap of the dense zone block (8 n^2 bytes, ~n^3 flops)
    double pcgRelativeTolerance = 1e-8;  ///< PCG: on ||r|| / ||b||
    int pcgMaxIterations = 2000;         ///< PCG: bound per secondary solve
    /// The primary's element with a neo-Hookean model (MaterialLaw::neoHookean): TLED over the
    /// primary cells (palp/fem/tled.h), the secondary staying linear (the law's small-strain
    /// stiffness); unused for a linear model.
    TledOptions tled;
    double safetyFactor = 0.9;  ///< primary substep = safety * critical step, (0, 1]
    int maxSubsteps = 64;       ///< bound on primary substeps per tick
    bool threaded = false;      ///< secondary on its own thread (else synchronous)
    int secondaryThreads = 1;   ///< concurrency of the secondary's tbb::task_arena
    int secondaryCpu = -1;      ///< threaded: pin the secondary thread to this CPU (-1: no pinning)
    int maxPrimaryNodes = 0;    ///< > primaryNodes enables the adaptive primary (synchronous)
    int adaptiveLevels = 4;     ///< number of prepared layouts between the two sizes
    double strainAtMax = 0.05;  ///< contact strain at which the size is maximal
    double strainReferenceLength = 0.06;  ///< metres, divides |u_contact| to give the strain
};

/// What AsyncRegions::watchedChanges() found.
struct WatchedChanges {
    std::size_t examined = 0;  ///< watched nodes looked at, from the first asked for
    std::size_t changed = 0;   ///< of them, written out (may differ from what is shown)
    double skippedMax2 = 0;    ///< largest |shown|^2 (m^2) among those passed over
};

/// What one tick did.
struct AsyncTickResult {
    /// Displacement drive: reaction at the contact, N. Force drive: the sum of the loads taken.
    Eigen::Vector3d contactForce = Eigen::Vector3d::Zero();
    /// Displacement of the first contact node at the end of the tick, m.
    Eigen::Vector3d contactDisplacement = Eigen::Vector3d::Zero();
    int loadsRefused = 0;           ///< force drive: loads refused (kAsyncLoadsRefused)
    int substeps = 0;               ///< primary substeps
    unsigned flags = 0;             ///< StepFlag bits
    bool secondaryUpdated = false;  ///< a new secondary solution entered at this tick
    bool layoutChanged = false;     ///< a layout for a new contact node was adopted at this tick
    /// tick(loads, spring): the coupling spring's mean force over the tick (impulse / tick), its
    /// last substep's force, a(u) at the end, whether it was clamped. Zero otherwise.
    SpringResult spring;
};

/// Counters of the secondary (read from the servo thread; threaded values are approximate).
struct AsyncSecondaryStats {
    std::uint64_t solves = 0;           ///< secondary solves finished
    std::uint64_t used = 0;             ///< solutions taken up by the primary
    double lastSolveSeconds = 0.0;      ///< wall time of the last solve
    double maxSolveSeconds = 0.0;       ///< longest solve so far
    double lastSolveCpuSeconds = 0.0;   ///< thread CPU time of the last solve (without preemption)
    int lastIterations = 0;             ///< PCG iterations of the last solve
    std::uint64_t layoutsPrepared = 0;  ///< layouts prepared for contact changes
    double lastPrepareSeconds = 0.0;    ///< wall time of the last preparation
};

/// The cells of the primary region a layout around @p contactNodes with @p seeds seed nodes
/// takes at level of detail @p lod (the seeds: the active nodes nearest the contact in graph
/// distance, ties by Euclidean distance; the cells touching them, widened to whole coarse
/// cells), as a mask over @p mesh's cells: the layouts' own rule, so that a primary's cost is
/// known without building it.
/// @throw palp::ValueError for a contact node that is not an active node, or lod < 1.
std::vector<std::uint8_t> primaryRegionCells(const HexMesh& mesh,
                                             const std::vector<int>& contactNodes, int seeds,
                                             int lod);

/// Primary region (explicit, every tick) coupled to a secondary region (implicit, f_s).
/// Displacement drive: the contact nodes are driven by a prescribed displacement (the same for
/// all of them); the contact force is their reaction, as ExplicitSolver::reactionSum() gives it.
/// Force drive: the contact nodes only centre the primary region; nodal loads drive the body.
class AsyncRegions {
  public:
    /// Builds the regions, the primary operator and the secondary system (assembly and, for
    /// CHOLMOD, a factorisation per layout: seconds for large meshes), and starts the secondary
    /// thread in threaded mode.
    /// @throw palp::ValueError for bad options, contact nodes outside the model or inactive, a
    /// lod that does not divide the cell counts, constraints that do not match the model, or
    /// non-zero prescribed displacements on secondary nodes, watch nodes that are repeated,
    /// inactive or outside the model, or maxLoads < 1.
    AsyncRegions(const FemModel& model, const Constraints& constraints,
                 std::vector<int> contactNodes, const AsyncRegionsOptions& options = {});
    ~AsyncRegions();
    AsyncRegions(const AsyncRegions&) = delete;
    AsyncRegions& operator=(const AsyncRegions&) = delete;

    /// Advances one servo tick with the contact nodes reaching @p contactDisplacement (metres)
    /// at its end.
    /// @par Real-time  Threaded mode: noexcept, allocation-free, lock-free, at most maxSubsteps
    /// substeps over the primary cells. Synchronous mode: the same except at secondary period
    /// boundaries, where the secondary solve (and a layout change) runs inline.
    /// Displacement drive only (in force drive it does nothing and flags kStepBadForce).
    AsyncTickResult tick(const Eigen::Vector3d& contactDisplacement) noexcept;

    /// Advances one servo tick under the external nodal @p loads (N, held over the tick; several
    /// loads on one node add up). Force drive only (in displacement drive it does nothing and
    /// flags kStepBadForce). Loads beyond maxLoads, on bad nodes or non-finite are refused
    /// (kAsyncLoadsRefused, loadsRefused); loads on fixed dofs vanish into the support.
    /// @par Real-time  As the other tick().
    AsyncTickResult tick(std::span<const NodalLoad> loads) noexcept;
    /// tick(loads) with a coupling @p spring (coupling_spring.h) integrated with the tissue.
    /// Spring nodes in the primary P: the force `F = clamp(k (c - a(u)))` is evaluated at every
    /// primary substep from the current displacement and `w_i F` is added to their load for that
    /// substep. Spring nodes outside P (Gamma or secondary) enter a(u) with their shown
    /// displacement (nodeDisplacement(); an unwatched secondary node counts as zero: watch
    /// them or keep them in P) and take their share `w_i F` of the tick's mean force as an
    /// ordinary load (the secondary path, averaged over the period). On the capacitance
    /// secondary that share is condensed: F solves `(I + k C) F = k (c - a) + k C F~` with C the
    /// secondary's compliance over those nodes (3 x 3, from the zone block, per tick while some
    /// weight is outside P) and F~ the share the shown values answer, so a stiff spring on a
    /// lagging secondary (a late layout) settles instead of ringing (docs/algorithms.md). The
    /// substep is at most safetyFactor times criticalTimeStepWith(model, k sum_{i in P} w_i^2 /
    /// m_i), so the substep count may change from tick to tick (the half-step velocity is kept);
    /// when that needs more than maxSubsteps, maxSubsteps substeps of that step run (less time than
    /// a tick) and kStepSubstepLimit is flagged. Bad spring nodes are skipped and flagged
    /// (kAsyncLoadsRefused). result.spring holds the spring's mean and end force and end point.
    /// @par Real-time  As the other tick(); O(#spring nodes) more per substep, and O(|J|^2) per
    /// tick while the spring has weight outside P (the share's compliance).
    AsyncTickResult tick(std::span<const NodalLoad> loads, const CouplingSpring& spring) noexcept;

    /// Displacement of node @p node now, m: the primary's value on P and Gamma (Gamma as shown in
    /// the last substep), the constraint value on fixed dofs, the time-interpolated secondary
    /// value on other watched nodes; NaN for an unwatched secondary node or a bad index.
    /// @par Real-time  noexcept, allocation-free, lock-free, O(1). Servo thread.
    Eigen::Vector3d nodeDisplacement(int node) const noexcept;
    /// nodeDisplacement() of every watched node, in watchNodes order, into @p out (at most
    /// out.size() entries). @return the number written. @par Real-time  O(#watched).
    std::size_t watchedDisplacements(std::span<Eigen::Vector3d> out) const noexcept;
    /// nodeDisplacement() of the watched nodes @p first, @p first + 1, ... (watchNodes order)
    /// into @p out, in one pass over the interpolated values (a slice of a surface sweep).
    /// @return the number written (out.size(), fewer at the end of the list).
    /// @par Real-time  O(out.size()), no per-node call. Servo thread.
    std::size_t watchedDisplacements(std::size_t first,
                                     std::span<Eigen::Vector3d> out) const noexcept;
    /// A sweep's step that passes over what has not changed: of the watched nodes @p first,
    /// @p first + 1, ... (at most @p count examined), those whose nodeDisplacement() may
    /// differ from @p shown (3 values per watched node, watchNodes order: what the caller shows
    /// of them) by @p still (m) or more in a component: their watch index into @p index and
    /// their nodeDisplacement() into @p out, in order, as many as both hold (the examination
    /// stops before the first that does not fit). A node is passed over only when it is shown
    /// from the secondary alone (not on P or Gamma, active, no fixed dof) and both ends of its
    /// interpolation over the period lie within @p still of @p shown, so nodeDisplacement() is
    /// within @p still of it now: a surface sweep that skips such nodes anyway shows the same
    /// surface, without reading each node's state (9 in 10 nodes of the head CT's far skin).
    /// @par Real-time  O(examined), no per-node call. Servo thread.
    WatchedChanges watchedChanges(std::size_t first, std::size_t count,
                                  std::span<const double> shown, double still,
                                  std::span<std::uint32_t> index,
                                  std::span<Eigen::Vector3d> out) const noexcept;
    /// The watched nodes (options().watchNodes).
    const std::vector<int>& watchNodes() const;

    /// Fine nodes of the current primary region (sorted).
    const std::vector<int>& primaryNodes() const;
    /// Number of primary nodes that are not fully fixed (the "N" of the thesis's table).
    int primaryFreeNodeCount() const;
    /// Fine secondary-border nodes (Gamma) of the current layout.
    const std::vector<int>& secondaryBorderNodes() const;
    /// Number of cells the primary integrates.
    int primaryCellCount() const;
    /// Secondary unknowns (coarse dofs).
    int secondaryDofCount() const;
    /// Index of the current layout (0 = smallest primary; adaptive mode only changes it).
    int layoutIndex() const;
    /// Contact nodes of the current layout (the driven nodes).
    const std::vector<int>& contactNodes() const;

    /// Asks for the contact to move to @p node (a single node; see "Contact changes" above).
    /// The change takes effect at the tick that adopts the prepared layout
    /// (AsyncTickResult::layoutChanged); contactNodes() tells which node is driven.
    /// @return false (and nothing changes) if @p node is not an active node of the mesh.
    /// @par Real-time  noexcept, allocation-free, lock-free (one atomic store).
    bool requestContactNode(int node) noexcept;
    /// Ticks per secondary period.
    int periodTicks() const;
    /// Primary substep, seconds.
    double substepSeconds() const;
    /// Simulated time, seconds.
    double time() const;

    /// Whole fine displacement field, metres (#dofs): primary values on P, the secondary's
    /// latest solution interpolated to the fine grid elsewhere. Not real-time (allocates).
    Eigen::VectorXd displacement() const;

    /// Secondary counters.
    AsyncSecondaryStats secondaryStats() const;

    /// Size in coarse dofs of the zone block a body built with these arguments would invert for
    /// its sliding contact (see "Sliding contact"; 0 without slide nodes). Above
    /// options.slideZoneMaxDofs every contact move is factorised (seconds), so a sliding contact
    /// is not followed: choose a coarser lod or fewer primaryNodes then. O(nodes), no assembly.
    /// @throw palp::ValueError as the constructor does for bad options or contact nodes.
    static int slideZoneDofs(const FemModel& model, const Constraints& constraints,
                             const std::vector<int>& contactNodes,
                             const AsyncRegionsOptions& options);

    /// Test hook: while true, the secondary thread stops solving (it neither reads snapshots nor
    /// publishes), as a secondary that has fallen far behind would. Threaded mode only.
    void setSecondaryStalledForTest(bool stalled) noexcept;
    /// Test hook: every later layout build for a contact change takes at least @p seconds more
    /// (as on a loaded core, or a larger body). Threaded mode only.
    void setBuildDelayForTest(double seconds) noexcept;

  private:
    struct Impl;
    std::unique_ptr<Impl> mImpl;
};

}  // namespace palp::fem
