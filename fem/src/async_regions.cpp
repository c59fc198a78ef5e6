#include "palp/fem/async_regions.h"

#include <pthread.h>
#include <sched.h>
#include <sys/resource.h>
#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <tbb/parallel_reduce.h>
#include <tbb/task_arena.h>
#include <unistd.h>

#include <Eigen/CholmodSupport>
#include <Eigen/SparseCore>
#include <algorithm>
#include <array>
#include <atomic>
#include <chrono>
#include <cmath>
#include <ctime>
#include <limits>
#include <queue>
#include <sstream>
#include <thread>

#include "palp/base/error.h"
#include "palp/base/parallel.h"

namespace palp::fem {

namespace {

std::size_t sz(int v) { return static_cast<std::size_t>(v); }

using RowMatrix = Eigen::SparseMatrix<double, Eigen::RowMajor, int>;
using Triplet = Eigen::Triplet<double, int>;

/// Single-producer single-consumer triple buffer: the writer fills back() and publish()es it; the
/// reader calls update() and, when it returns true, reads the newest published slot at front().
/// Wait-free on both sides; the slots are preallocated by the owner.
template <class T>
class TripleBuffer {
  public:
    T& slot(int i) { return mSlots[sz(i)]; }
    T& back() noexcept { return mSlots[mBack]; }
    void publish() noexcept {
        mBack = mMiddle.exchange(mBack | kDirty, std::memory_order_acq_rel) & 3u;
    }
    bool update() noexcept {
        if ((mMiddle.load(std::memory_order_relaxed) & kDirty) == 0) return false;
        mFront = mMiddle.exchange(mFront, std::memory_order_acq_rel) & 3u;
        return true;
    }
    const T& front() const noexcept { return mSlots[mFront]; }

  private:
    static constexpr unsigned kDirty = 4u;
    std::array<T, 3> mSlots;
    std::atomic<unsigned> mMiddle{1u};
    unsigned mBack = 0u;   // writer-owned
    unsigned mFront = 2u;  // reader-owned
};

/// Border data crossing threads, preallocated.
struct Packet {
    std::vector<double> values;
    // Snapshots, force drive: period-averaged loads on secondary dofs (fine dof, newtons).
    std::vector<int> loadDofs;
    std::vector<double> loadValues;
    int loadCount = 0;
    double time = 0.0;
    std::uint64_t sequence = 0;
    std::uint64_t generation = 0;  // layout the values belong to
};

/// One arrangement of the regions with its secondary system.
struct Layout {
    int seeds = 0;
    std::uint64_t generation = 0;                // unique per prepared layout
    std::vector<int> contactNodes, contactDofs;  // driven nodes (always in P)
    // State handed to the primary at a contact change: fine dofs of P and Gamma that were
    // secondary interior before, with the secondary's latest values there.
    std::vector<int> entryDofs;
    std::vector<double> entryValues;
    std::vector<int> primaryNodes;             // P, sorted
    std::vector<std::uint8_t> isPrimary;       // per fine node
    std::vector<std::array<int, 8>> cellDofs;  // 3 * node of the 8 nodes of each primary cell
    std::vector<double> cellE;                 // Young's modulus per primary cell
    std::vector<int> touchedDofs;              // dofs of all nodes of primary cells
    std::vector<int> freeDofs;                 // free P dofs the primary integrates
    std::vector<int> gammaNodes, gammaDofs;    // secondary border: free S dofs of primary cells
    std::vector<std::uint8_t> isGamma;         // per fine node
    std::vector<int> borderDofs;               // P dofs coupled to the secondary
    int freeNodeCount = 0;
    // Secondary (coarse unknowns).
    std::vector<int> unknownCoarseDof;  // unknown -> coarse dof
    RowMatrix interp;                   // fine dofs x unknowns (rows of P / fixed dofs empty)
    RowMatrix interpGamma;              // gamma dofs x unknowns
    RowMatrix interpWatch;              // 3 * #watched x unknowns (rows of interp)
    SparseMatrix kc, mc;                // unknowns x unknowns
    RowMatrix kcb;                      // unknowns x border dofs
    Eigen::CholmodSupernodalLLT<SparseMatrix, Eigen::Lower> cholmod;
    RowMatrix rowA;
    Eigen::VectorXd inverseDiagonal;
    RowMatrix response;  // G: gamma dofs x border dofs (condensed coupling), small entries dropped
    // Quasi-static CHOLMOD secondary: the exact Gamma response to the border (dense), so that a
    // secondary solve needs only Gamma = R u_B; the whole field x is solved when asked for.
    Eigen::MatrixXd gammaResponse;
    Eigen::MatrixXd watchResponse;  // the same for the watched dofs (3 * #watched x border)
    bool fieldStale = false;        // x (and uC) lag the last border (direct Gamma solves)
    // Secondary work vectors (secondary thread only).
    Eigen::VectorXd x, v, a, rhs, xNew, yc, ym, r, z, p, q, border;
};

struct NewmarkCoefficients {
    double a0 = 0, a1 = 0, a2 = 0, a3 = 0, a4 = 0, a5 = 0;
};

NewmarkCoefficients coefficients(Integrator integrator, double dt) {
    NewmarkCoefficients c;
    if (integrator == Integrator::newmark) {
        constexpr double beta = 0.25, gamma = 0.5;
        c.a0 = 1.0 / (beta * dt * dt);
        c.a1 = gamma / (beta * dt);
        c.a2 = 1.0 / (beta * dt);
        c.a3 = 1.0 / (2.0 * beta) - 1.0;
        c.a4 = gamma / beta - 1.0;
        c.a5 = dt * (gamma / (2.0 * beta) - 1.0);
    } else if (integrator == Integrator::backwardEuler) {
        c.a0 = 1.0 / (dt * dt);
        c.a1 = 1.0 / dt;
        c.a2 = 1.0 / dt;
    }
    return c;
}

void pinCurrentThread(int cpu) {
    if (cpu < 0) return;
    cpu_set_t set;
    CPU_ZERO(&set);
    CPU_SET(static_cast<unsigned>(cpu), &set);
    pthread_setaffinity_np(pthread_self(), sizeof(set), &set);
}

}  // namespace

struct AsyncRegions::Impl {
    const FemModel& model;
    AsyncRegionsOptions options;
    bool forceDrive = false;
    std::vector<int> watchIndex;      // per fine node: index in options.watchNodes, or -1
    std::vector<std::uint8_t> fixed;  // per fine dof: constrained by the caller
    std::vector<std::uint8_t> nonZeroPrescribed;  // per fine node
    int lod = 1;
    std::array<int, 3> coarseCounts{};
    int coarseDofs = 0;
    SparseMatrix stiffness;  // fine K
    std::vector<std::unique_ptr<Layout>> layouts;
    int current = 0;
    int period = 1;
    double periodSeconds = 0.0;
    NewmarkCoefficients nm;
    double sK = 1.0, sM = 0.0;

    // Primary state (servo thread).
    double dtSub = 0.0;
    int substeps = 1;
    double time = 0.0;
    std::uint64_t ticks = 0;
    Eigen::VectorXd u, uPrev, fInt, work, invDen, prevCoef, twoMass, contactStart;
    // Coupling state, sized to the dof count once so that a layout change never allocates;
    // the first |Gamma| / |border| entries are used.
    std::vector<double> gPrev, gCur;  // Gamma values the interpolation runs between
    Eigen::VectorXd bPrev, bCur;      // primary border values those Gamma values answer
    Eigen::VectorXd bNow, gFix;       // condensed coupling work vectors
    double gStart = 0.0;
    // Watched secondary values the interpolation runs between (3 per watched node).
    std::vector<double> wPrev, wCur;
    // Force drive (servo thread): loads on free primary dofs this tick, and the sum over the
    // current period of the loads on secondary nodes.
    Eigen::VectorXd fExt, fAcc;
    std::vector<int> fExtDofs;  // capacity 3 * maxLoads
    std::size_t fExtCount = 0;
    std::vector<int> accNodes;  // nodes with a non-zero fAcc entry, capacity #nodes
    std::size_t accCount = 0;
    std::vector<std::uint8_t> accMark;  // per node

    // Secondary state in full coarse dof indexing (secondary thread in threaded mode).
    Eigen::VectorXd uC, vC, aC;

    // Threaded mode.
    TripleBuffer<Packet> snapshots, results;
    std::thread worker;
    std::atomic<bool> stop{false}, stalled{false};
    std::atomic<std::uint64_t> solves{0}, used{0};
    std::atomic<double> lastSolve{0.0}, maxSolve{0.0}, lastSolveCpu{0.0};
    std::atomic<int> lastIterations{0};
    std::unique_ptr<tbb::task_arena> arena;

    // Contact changes: the servo stores the requested node; the secondary thread (threaded) or
    // the period boundary (synchronous) prepares a layout for it; the servo adopts a prepared
    // layout with one pointer exchange and hands the old one back for deletion.
    std::atomic<int> requested{-1};
    int rejected = -1;                      // preparer-owned: a request that failed to build
    std::atomic<Layout*> pending{nullptr};  // prepared, not yet adopted (secondary -> servo)
    std::atomic<Layout*> retired{nullptr};  // adopted over, to delete (servo -> secondary)
    mutable std::atomic<std::uint64_t> nextGeneration{1};
    std::atomic<std::uint64_t> prepared{0};
    std::atomic<double> lastPrepare{0.0};

    Impl(const FemModel& m, const Constraints& c, std::vector<int> contactNodes,
         const AsyncRegionsOptions& o);
    ~Impl();

    std::unique_ptr<Layout> buildLayout(const std::vector<int>& contactNodes, int seedCount) const;
    void prepareSolver(Layout& layout) const;
    std::unique_ptr<Layout> buildPrepared(int node, int seeds) const;
    void finishForContact(Layout& from, Layout& next, std::chrono::steady_clock::time_point begin);
    std::unique_ptr<Layout> prepareForContact(Layout& from, int node, int seeds);
    void adoptLayout(const Layout& from, const Layout& to) noexcept;
    bool contactChangeWanted(const Layout& layout, int want) const noexcept;
    bool solveSecondary(Layout& layout, const double* border, const Packet* loads, double* gammaOut,
                        double* watchOut) noexcept;
    void refreshField(Layout& layout);
    void switchLayout(int next);
    void secondaryLoop();
    void setGamma(const Layout& layout, double* target, double t, bool product) noexcept;
    void acceptSolution(const double* gamma, const double* border, const double* watch) noexcept;
    void seedWatched(const Layout& from) noexcept;
    /// f(dof, value) for every free dof of the nodes of `to`'s P and Gamma that `from` showed
    /// from its secondary (interior secondary nodes): value = the secondary's latest solution.
    template <class F>
    void forEachEnteringDof(const Layout& from, const Layout& to, F&& f) const;
    Eigen::Vector3d shown(const Layout& layout, int node, double frac) const noexcept;
    double shownFraction() const noexcept;
    void takeLoads(std::span<const NodalLoad> loads, AsyncTickResult& result) noexcept;
    void packLoads(Packet& out) noexcept;
    AsyncTickResult advance(const Eigen::Vector3d& contactDisplacement,
                            std::span<const NodalLoad> loads) noexcept;
    void sizeCoupling(const Layout& layout) noexcept;
    void primarySubsteps(const Eigen::Vector3d& target, AsyncTickResult& result) noexcept;
};

AsyncRegions::Impl::Impl(const FemModel& m, const Constraints& c, std::vector<int> contactNodes,
                         const AsyncRegionsOptions& o)
    : model(m), options(o) {
    std::vector<int> contact = std::move(contactNodes);
    const HexMesh& mesh = model.mesh();
    const int dofs = model.dofCount();
    auto fail = [](const std::string& what, const std::string& expected, auto found) {
        std::ostringstream s;
        s << "async regions " << what << ": expected " << expected << ", found " << found;
        throw ValueError(s.str());
    };
    if (c.dofCount() != dofs) fail("constraints", std::to_string(dofs) + " dofs", c.dofCount());
    if (!(o.tickSeconds > 0.0) || !std::isfinite(o.tickSeconds))
        fail("tick", "a finite period > 0 s", o.tickSeconds);
    if (!(o.secondaryRate > 0.0) || !std::isfinite(o.secondaryRate))
        fail("secondary rate", "a finite rate > 0 Hz", o.secondaryRate);
    if (o.lod != 1 && o.lod != 2 && o.lod != 4) fail("lod", "1, 2 or 4", o.lod);
    if (!(o.safetyFactor > 0.0 && o.safetyFactor <= 1.0))
        fail("safety factor", "a value in (0, 1]", o.safetyFactor);
    if (o.maxSubsteps < 1) fail("max substeps", ">= 1", o.maxSubsteps);
    if (o.secondaryThreads < 1) fail("secondary threads", ">= 1", o.secondaryThreads);
    if (o.secondarySolver == LinearSolverKind::simplicialLdlt)
        fail("secondary solver", "cholmod or pcg", "simplicialLdlt");
    if (contact.empty()) fail("contact nodes", "at least one node", "none");
    if (o.maxLoads < 1) fail("max loads", ">= 1", o.maxLoads);
    forceDrive = o.drive == ContactDrive::force;
    watchIndex.assign(sz(mesh.nodeCount()), -1);
    for (std::size_t i = 0; i < o.watchNodes.size(); ++i) {
        const int n = o.watchNodes[i];
        if (n < 0 || n >= mesh.nodeCount() || !mesh.nodeActive()[sz(n)])
            fail("watch node", "an active node of the mesh", n);
        if (watchIndex[sz(n)] >= 0) fail("watch node", "distinct nodes", n);
        watchIndex[sz(n)] = static_cast<int>(i);
    }
    for (int n : contact) {
        if (n < 0 || n >= mesh.nodeCount() || !mesh.nodeActive()[sz(n)])
            fail("contact node", "an active node of the mesh", n);
    }
    if (o.primaryNodes < static_cast<int>(contact.size()))
        fail("primary nodes", ">= the number of contact nodes", o.primaryNodes);
    const bool adaptive = o.maxPrimaryNodes > o.primaryNodes;
    if (adaptive && o.threaded) fail("adaptive primary", "synchronous mode", "threaded mode");
    if (adaptive &&
        (o.adaptiveLevels < 2 || !(o.strainAtMax > 0.0) || !(o.strainReferenceLength > 0.0)))
        fail("adaptive primary", "levels >= 2 and positive strain scales", o.adaptiveLevels);
    lod = o.lod;
    for (int a = 0; a < 3; ++a) {
        const int cells = mesh.nodeCounts()[sz(a)] - 1;
        if (cells % lod != 0) fail("lod", "a factor of every cell count", cells);
        coarseCounts[sz(a)] = cells / lod + 1;
    }
    coarseDofs = 3 * coarseCounts[0] * coarseCounts[1] * coarseCounts[2];

    fixed.assign(sz(dofs), 0);
    nonZeroPrescribed.assign(sz(mesh.nodeCount()), 0);
    for (int d = 0; d < dofs; ++d) {
        fixed[sz(d)] = c.isFixed(d) ? 1 : 0;
        if (c.isFixed(d) && c.values()[d] != 0.0) nonZeroPrescribed[sz(d / 3)] = 1;
    }

    period = std::max(1, static_cast<int>(std::lround(1.0 / (o.secondaryRate * o.tickSeconds))));
    periodSeconds = period * o.tickSeconds;
    if (o.secondaryIntegrator == Integrator::quasiStatic) {
        sK = 1.0;
        sM = 0.0;
    } else {
        nm = coefficients(o.secondaryIntegrator, periodSeconds);
        sK = 1.0 + nm.a1 * model.material().dampingBeta;
        sM = nm.a0 + nm.a1 * model.material().dampingAlpha;
    }

    // Primary state and central-difference coefficients (the same for every layout).
    const double critical = o.safetyFactor * model.criticalTimeStep();
    substeps =
        std::min(o.maxSubsteps, std::max(1, static_cast<int>(std::ceil(o.tickSeconds / critical))));
    dtSub = o.tickSeconds / substeps;
    u = Eigen::VectorXd::Zero(dofs);
    for (int d = 0; d < dofs; ++d) {
        if (c.isFixed(d)) u[d] = c.values()[d];
    }
    for (int n : contact) {
        for (int k = 0; k < 3; ++k) u[3 * n + k] = 0.0;
    }
    uPrev = u;
    fInt = Eigen::VectorXd::Zero(dofs);
    work = u;
    invDen = Eigen::VectorXd::Zero(dofs);
    prevCoef = Eigen::VectorXd::Zero(dofs);
    twoMass = Eigen::VectorXd::Zero(dofs);
    const Eigen::VectorXd& mass = model.lumpedMass();
    const double alpha = model.material().dampingAlpha;
    for (int d = 0; d < dofs; ++d) {
        if (fixed[sz(d)] || mass[d] <= 0.0) continue;
        invDen[d] = 1.0 / (mass[d] + 0.5 * dtSub * alpha * mass[d]);
        prevCoef[d] = mass[d] - 0.5 * dtSub * alpha * mass[d];
        twoMass[d] = 2.0 * mass[d];
    }
    contactStart = Eigen::VectorXd::Zero(dofs);
    gPrev.assign(sz(dofs), 0.0);
    gCur = gPrev;
    bPrev = Eigen::VectorXd::Zero(dofs);
    bCur = bPrev;
    bNow = bPrev;
    gFix = bPrev;
    wPrev.assign(3 * o.watchNodes.size(), 0.0);
    wCur = wPrev;
    fExt = Eigen::VectorXd::Zero(dofs);
    fAcc = fExt;
    fExtDofs.assign(3 * sz(o.maxLoads), 0);
    accNodes.assign(sz(mesh.nodeCount()), 0);
    accMark.assign(sz(mesh.nodeCount()), 0);
    // Cross-thread packets (also the synchronous mode's work buffers), sized once for any
    // layout: Gamma and the primary border are disjoint sets of dofs.
    for (int i = 0; i < 3; ++i) {
        snapshots.slot(i).values.assign(sz(dofs), 0.0);
        snapshots.slot(i).loadDofs.assign(sz(dofs), 0);
        snapshots.slot(i).loadValues.assign(sz(dofs), 0.0);
        results.slot(i).values.assign(sz(dofs) + wPrev.size(), 0.0);
    }

    stiffness = model.assembleStiffness();
    uC = Eigen::VectorXd::Zero(coarseDofs);
    vC = uC;
    aC = uC;
    arena = std::make_unique<tbb::task_arena>(o.secondaryThreads);

    // Layouts: one, or adaptiveLevels sizes from primaryNodes to maxPrimaryNodes.
    const int levels = adaptive ? o.adaptiveLevels : 1;
    for (int k = 0; k < levels; ++k) {
        const int seeds =
            levels == 1
                ? o.primaryNodes
                : o.primaryNodes + static_cast<int>(std::lround(
                                       static_cast<double>(k) *
                                       (o.maxPrimaryNodes - o.primaryNodes) / (levels - 1)));
        layouts.push_back(buildLayout(contact, seeds));
        arena->execute([&] { prepareSolver(*layouts.back()); });
    }
    sizeCoupling(*layouts[0]);

    if (o.threaded) worker = std::thread([this] { secondaryLoop(); });
}

AsyncRegions::Impl::~Impl() {
    stop.store(true, std::memory_order_release);
    if (worker.joinable()) worker.join();
    delete pending.exchange(nullptr);
    delete retired.exchange(nullptr);
}

void AsyncRegions::Impl::sizeCoupling(const Layout& L) noexcept {
    // Gamma and the border start from the values the primary shows now.
    for (std::size_t i = 0; i < L.gammaDofs.size(); ++i) {
        gPrev[i] = u[L.gammaDofs[i]];
        gCur[i] = gPrev[i];
    }
    for (std::size_t i = 0; i < L.borderDofs.size(); ++i) {
        const Eigen::Index k = static_cast<Eigen::Index>(i);
        bPrev[k] = u[L.borderDofs[i]];
        bCur[k] = bPrev[k];
    }
    gStart = time;
}

std::unique_ptr<Layout> AsyncRegions::Impl::buildLayout(const std::vector<int>& contact,
                                                        int seedCount) const {
    const HexMesh& mesh = model.mesh();
    const auto& nc = mesh.nodeCounts();
    const int nodes = mesh.nodeCount();
    const auto& active = mesh.nodeActive();
    auto layout = std::make_unique<Layout>();
    Layout& L = *layout;
    L.seeds = seedCount;
    L.generation = nextGeneration.fetch_add(1, std::memory_order_relaxed);
    L.contactNodes = contact;
    // Displacement drive: the contact dofs are driven, fixed for this layout. Force drive: they
    // are free and only centre the regions.
    std::vector<std::uint8_t> driven = fixed;
    for (int n : contact) {
        if (forceDrive) break;
        for (int k = 0; k < 3; ++k) {
            L.contactDofs.push_back(3 * n + k);
            driven[sz(3 * n + k)] = 1;
        }
    }

    // Graph distance over lattice edges between active nodes (BFS from all contact nodes).
    std::vector<int> dist(sz(nodes), -1);
    std::queue<int> frontier;
    for (int n : contact) {
        if (dist[sz(n)] < 0) {
            dist[sz(n)] = 0;
            frontier.push(n);
        }
    }
    while (!frontier.empty()) {
        const int n = frontier.front();
        frontier.pop();
        const auto ijk = mesh.nodeCoords(n);
        for (int a = 0; a < 3; ++a) {
            for (int s = -1; s <= 1; s += 2) {
                std::array<int, 3> q = ijk;
                q[sz(a)] += s;
                if (q[sz(a)] < 0 || q[sz(a)] >= nc[sz(a)]) continue;
                const int m = mesh.node(q[0], q[1], q[2]);
                if (!active[sz(m)] || dist[sz(m)] >= 0) continue;
                dist[sz(m)] = dist[sz(n)] + 1;
                frontier.push(m);
            }
        }
    }
    std::vector<std::pair<double, int>> order;
    for (int n = 0; n < nodes; ++n) {
        if (dist[sz(n)] < 0) continue;
        double e = std::numeric_limits<double>::infinity();
        for (int cn : contact)
            e = std::min(e, (mesh.nodePosition(n) - mesh.nodePosition(cn)).norm());
        order.emplace_back(dist[sz(n)] * 1e6 + e / mesh.edge(), n);
    }
    std::sort(order.begin(), order.end());
    const std::size_t seeds = std::min(order.size(), sz(seedCount));

    // Primary cells: cells touching a seed, widened to whole coarse cells.
    const std::array<int, 3> cc = mesh.cellCounts();
    std::vector<std::uint8_t> primaryCell(sz(mesh.cellCount()), 0);
    for (std::size_t s = 0; s < seeds; ++s) {
        const auto ijk = mesh.nodeCoords(order[s].second);
        for (int dk = -1; dk <= 0; ++dk) {
            for (int dj = -1; dj <= 0; ++dj) {
                for (int di = -1; di <= 0; ++di) {
                    const int ci = ijk[0] + di, cj = ijk[1] + dj, ck = ijk[2] + dk;
                    if (ci < 0 || cj < 0 || ck < 0 || ci >= cc[0] || cj >= cc[1] || ck >= cc[2])
                        continue;
                    if (!mesh.cellActive(mesh.cell(ci, cj, ck))) continue;
                    const int bi = ci / lod * lod, bj = cj / lod * lod, bk = ck / lod * lod;
                    for (int k = bk; k < bk + lod; ++k) {
                        for (int j = bj; j < bj + lod; ++j) {
                            for (int i = bi; i < bi + lod; ++i) {
                                primaryCell[sz(mesh.cell(i, j, k))] = 1;
                            }
                        }
                    }
                }
            }
        }
    }
    // P: active nodes all of whose active cells are primary.
    std::vector<std::uint8_t> touchesPrimary(sz(nodes), 0), touchesSecondary(sz(nodes), 0);
    for (int c = 0; c < mesh.cellCount(); ++c) {
        if (!mesh.cellActive(c)) continue;
        for (int n : mesh.cellNodes(c)) {
            (primaryCell[sz(c)] ? touchesPrimary : touchesSecondary)[sz(n)] = 1;
        }
    }
    L.isPrimary.assign(sz(nodes), 0);
    for (int n = 0; n < nodes; ++n) {
        if (touchesPrimary[sz(n)] && !touchesSecondary[sz(n)]) {
            L.isPrimary[sz(n)] = 1;
            L.primaryNodes.push_back(n);
            bool allFixed = true;
            for (int k = 0; k < 3; ++k) allFixed = allFixed && driven[sz(3 * n + k)];
            if (!allFixed || std::find(contact.begin(), contact.end(), n) != contact.end())
                ++L.freeNodeCount;
        }
    }
    const Eigen::VectorXd& mass = model.lumpedMass();
    for (int c = 0; c < mesh.cellCount(); ++c) {
        if (!mesh.cellActive(c) || !primaryCell[sz(c)]) continue;
        std::array<int, 8> d{};
        const auto cn = mesh.cellNodes(c);
        for (int a = 0; a < 8; ++a) d[sz(a)] = 3 * cn[sz(a)];
        L.cellDofs.push_back(d);
        L.cellE.push_back(mesh.cellYoungs()[sz(c)]);
    }
    for (int n = 0; n < nodes; ++n) {
        if (!touchesPrimary[sz(n)]) continue;
        for (int k = 0; k < 3; ++k) {
            const int d = 3 * n + k;
            L.touchedDofs.push_back(d);
            const bool free = !driven[sz(d)] && mass[d] > 0.0;
            if (L.isPrimary[sz(n)]) {
                if (free) L.freeDofs.push_back(d);
            } else if (free) {
                L.gammaDofs.push_back(d);
            }
        }
        if (!L.isPrimary[sz(n)]) L.gammaNodes.push_back(n);
    }
    L.isGamma.assign(sz(nodes), 0);
    for (int n : L.gammaNodes) L.isGamma[sz(n)] = 1;

    // Interpolation from the coarse secondary: each free fine S dof takes trilinear weights of
    // the corners of a secondary coarse cell containing its node.
    const std::array<int, 3> ccc{coarseCounts[0] - 1, coarseCounts[1] - 1, coarseCounts[2] - 1};
    auto coarseCellSecondary = [&](int I, int J, int K) {
        bool anyActive = false;
        for (int k = K * lod; k < (K + 1) * lod; ++k) {
            for (int j = J * lod; j < (J + 1) * lod; ++j) {
                for (int i = I * lod; i < (I + 1) * lod; ++i) {
                    const int c = mesh.cell(i, j, k);
                    if (primaryCell[sz(c)]) return false;
                    anyActive = anyActive || mesh.cellActive(c);
                }
            }
        }
        return anyActive;
    };
    std::vector<int> unknownOf(sz(coarseDofs), -1);
    std::vector<Triplet> trip;
    std::vector<int> rowOfFine(sz(3 * nodes), -1);
    for (int n = 0; n < nodes; ++n) {
        if (!active[sz(n)] || L.isPrimary[sz(n)]) continue;
        const auto ijk = mesh.nodeCoords(n);
        // Candidate coarse cells along each axis.
        std::array<std::array<int, 2>, 3> cand{};
        std::array<int, 3> candCount{};
        for (int a = 0; a < 3; ++a) {
            const int q = ijk[sz(a)] / lod;
            int count = 0;
            if (q < ccc[sz(a)]) cand[sz(a)][sz(count++)] = q;
            if (ijk[sz(a)] % lod == 0 && q - 1 >= 0) cand[sz(a)][sz(count++)] = q - 1;
            candCount[sz(a)] = count;
        }
        int I = -1, J = -1, K = -1;
        for (int a = 0; a < candCount[0] && I < 0; ++a) {
            for (int b = 0; b < candCount[1] && I < 0; ++b) {
                for (int e = 0; e < candCount[2] && I < 0; ++e) {
                    if (coarseCellSecondary(cand[0][sz(a)], cand[1][sz(b)], cand[2][sz(e)])) {
                        I = cand[0][sz(a)];
                        J = cand[1][sz(b)];
                        K = cand[2][sz(e)];
                    }
                }
            }
        }
        if (I < 0) continue;  // no secondary cell (cannot happen on a box): held at rest
        for (int k = 0; k < 3; ++k) {
            const int d = 3 * n + k;
            if (driven[sz(d)] || mass[d] <= 0.0) continue;
            for (int corner = 0; corner < 8; ++corner) {
                const int X = I + (corner & 1), Y = J + ((corner >> 1) & 1), Z = K + (corner >> 2);
                const double w = (1.0 - std::abs(ijk[0] - X * lod) / static_cast<double>(lod)) *
                                 (1.0 - std::abs(ijk[1] - Y * lod) / static_cast<double>(lod)) *
                                 (1.0 - std::abs(ijk[2] - Z * lod) / static_cast<double>(lod));
                if (w == 0.0) continue;
                const int fineCorner = mesh.node(X * lod, Y * lod, Z * lod);
                const int fineDof = 3 * fineCorner + k;
                if (driven[sz(fineDof)] || L.isPrimary[sz(fineCorner)]) continue;
                const int coarseDof = 3 * (X + coarseCounts[0] * (Y + coarseCounts[1] * Z)) + k;
                int& idx = unknownOf[sz(coarseDof)];
                if (idx < 0) {
                    idx = static_cast<int>(L.unknownCoarseDof.size());
                    L.unknownCoarseDof.push_back(coarseDof);
                }
                trip.emplace_back(d, idx, w);
            }
        }
    }
    const int unknowns = static_cast<int>(L.unknownCoarseDof.size());
    const int dofs = model.dofCount();
    SparseMatrix interp(dofs, unknowns);
    interp.setFromTriplets(trip.begin(), trip.end());
    L.interp = interp;
    {
        std::vector<Triplet> g;
        for (std::size_t r = 0; r < L.gammaDofs.size(); ++r) {
            for (RowMatrix::InnerIterator it(L.interp, L.gammaDofs[r]); it; ++it)
                g.emplace_back(static_cast<int>(r), static_cast<int>(it.col()), it.value());
        }
        L.interpGamma.resize(static_cast<int>(L.gammaDofs.size()), unknowns);
        L.interpGamma.setFromTriplets(g.begin(), g.end());
        std::vector<Triplet> w;
        const std::vector<int>& watch = options.watchNodes;
        for (std::size_t i = 0; i < watch.size(); ++i) {
            for (int k = 0; k < 3; ++k) {
                for (RowMatrix::InnerIterator it(L.interp, 3 * watch[i] + k); it; ++it)
                    w.emplace_back(static_cast<int>(3 * i) + k, static_cast<int>(it.col()),
                                   it.value());
            }
        }
        L.interpWatch.resize(3 * static_cast<int>(watch.size()), unknowns);
        L.interpWatch.setFromTriplets(w.begin(), w.end());
    }
    const SparseMatrix interpT = interp.transpose();
    const SparseMatrix ik = interpT * stiffness;  // unknowns x fine dofs
    L.kc = ik * interp;
    Eigen::VectorXd m = mass;
    L.mc = interpT * m.asDiagonal() * interp;
    // Coupling to the P dofs: columns of I^T K at primary nodes that are not all zero.
    std::vector<Triplet> kb;
    for (int n : L.primaryNodes) {
        for (int k = 0; k < 3; ++k) {
            const int d = 3 * n + k;
            bool any = false;
            for (SparseMatrix::InnerIterator it(ik, d); it; ++it) {
                if (it.value() == 0.0) continue;
                if (!any) {
                    any = true;
                    L.borderDofs.push_back(d);
                }
                kb.emplace_back(static_cast<int>(it.row()),
                                static_cast<int>(L.borderDofs.size()) - 1, it.value());
            }
        }
    }
    L.kcb.resize(unknowns, static_cast<int>(L.borderDofs.size()));
    L.kcb.setFromTriplets(kb.begin(), kb.end());
    L.x = Eigen::VectorXd::Zero(unknowns);
    L.v = L.x;
    L.a = L.x;
    L.rhs = L.x;
    L.xNew = L.x;
    L.yc = L.x;
    L.ym = L.x;
    L.r = L.x;
    L.z = L.x;
    L.p = L.x;
    L.q = L.x;
    L.border = Eigen::VectorXd::Zero(static_cast<Eigen::Index>(L.borderDofs.size()));
    // Non-zero prescribed values on secondary nodes are not supported (the secondary's
    // right-hand side has no term for them).
    for (int n = 0; n < nodes; ++n) {
        if (nonZeroPrescribed[sz(n)] && !L.isPrimary[sz(n)]) {
            throw ValueError(
                "async regions constraints: expected zero prescribed displacement on secondary "
                "nodes, found a non-zero value at node " +
                std::to_string(n));
        }
    }
    return layout;
}

void AsyncRegions::Impl::refreshField(Layout& L) {
    if (!L.fieldStale) return;
    L.fieldStale = false;
    if (L.unknownCoarseDof.empty()) return;
    L.rhs.noalias() = -sK * (L.kcb * L.border);
    L.x = L.cholmod.solve(L.rhs);
    for (std::size_t i = 0; i < L.unknownCoarseDof.size(); ++i)
        uC[L.unknownCoarseDof[i]] = L.x[static_cast<Eigen::Index>(i)];
}

std::unique_ptr<Layout> AsyncRegions::Impl::buildPrepared(int node, int seeds) const {
    std::unique_ptr<Layout> next = buildLayout({node}, seeds);
    prepareSolver(*next);
    return next;
}

std::unique_ptr<Layout> AsyncRegions::Impl::prepareForContact(Layout& from, int node, int seeds) {
    const auto begin = std::chrono::steady_clock::now();
    std::unique_ptr<Layout> next = buildPrepared(node, seeds);
    finishForContact(from, *next, begin);
    return next;
}

void AsyncRegions::Impl::finishForContact(Layout& from, Layout& nextL,
                                          std::chrono::steady_clock::time_point begin) {
    Layout* next = &nextL;
    refreshField(from);
    // Entry state: nodes of the new P and Gamma that were interior secondary nodes of `from`
    // take the secondary's latest solution (the servo keeps its own values for the others).
    forEachEnteringDof(from, *next, [&](int d, double value) {
        next->entryDofs.push_back(d);
        next->entryValues.push_back(value);
    });
    // Warm state of the secondary in its own indexing.
    for (std::size_t i = 0; i < next->unknownCoarseDof.size(); ++i) {
        const Eigen::Index k = static_cast<Eigen::Index>(i);
        const int cd = next->unknownCoarseDof[i];
        next->x[k] = uC[cd];
        next->v[k] = vC[cd];
        next->a[k] = aC[cd];
    }
    lastPrepare.store(
        std::chrono::duration<double>(std::chrono::steady_clock::now() - begin).count(),
        std::memory_order_relaxed);
    prepared.fetch_add(1, std::memory_order_release);
}

bool AsyncRegions::Impl::contactChangeWanted(const Layout& L, int want) const noexcept {
    return want >= 0 && want != rejected &&
           !(L.contactNodes.size() == 1 && L.contactNodes[0] == want);
}

void AsyncRegions::Impl::adoptLayout(const Layout& from, const Layout& to) noexcept {
    // The border as the primary shows it now (current and previous substep); nodes the servo
    // did not integrate or show take the prepared secondary values; the coupling restarts from
    // the shown values, so nothing jumps at the swap.
    setGamma(from, u.data(), time, true);
    setGamma(from, uPrev.data(), time - dtSub, true);
    seedWatched(from);
    for (std::size_t i = 0; i < to.entryDofs.size(); ++i) {
        u[to.entryDofs[i]] = to.entryValues[i];
        uPrev[to.entryDofs[i]] = to.entryValues[i];
    }
    sizeCoupling(to);
}

void AsyncRegions::Impl::prepareSolver(Layout& L) const {
    if (L.unknownCoarseDof.empty()) return;
    SparseMatrix a = sK * L.kc + sM * L.mc;
    if (options.secondarySolver == LinearSolverKind::cholmod) {
        L.cholmod.compute(a);
        if (L.cholmod.info() != Eigen::Success) {
            std::ostringstream s;
            s << "async regions secondary: expected a positive definite system, found a failed "
                 "CHOLMOD factorisation ("
              << a.rows() << " unknowns; do the supports remove every rigid-body motion?)";
            throw ValueError(s.str());
        }
    } else {
        L.rowA = a;
        L.inverseDiagonal = a.diagonal().cwiseInverse();
    }
    const bool direct = options.secondarySolver == LinearSolverKind::cholmod &&
                        options.secondaryIntegrator == Integrator::quasiStatic &&
                        !options.secondaryFullField;
    if ((options.condensed || direct) && !L.borderDofs.empty() && !L.gammaDofs.empty()) {
        Eigen::CholmodSupernodalLLT<SparseMatrix, Eigen::Lower> own;
        Eigen::CholmodSupernodalLLT<SparseMatrix, Eigen::Lower>* llt = &L.cholmod;
        if (options.secondarySolver != LinearSolverKind::cholmod) {
            own.compute(a);
            llt = &own;
        }
        const Eigen::MatrixXd rhs = -sK * Eigen::MatrixXd(L.kcb);
        const Eigen::MatrixXd x = llt->solve(rhs);
        const Eigen::MatrixXd g = L.interpGamma * x;
        if (direct) {
            L.gammaResponse = g;
            if (L.interpWatch.rows() > 0) L.watchResponse = L.interpWatch * x;
        }
        if (!options.condensed) return;
        const double drop = options.condensedDropTolerance * g.cwiseAbs().maxCoeff();
        std::vector<Triplet> t;
        for (Eigen::Index c = 0; c < g.cols(); ++c) {
            for (Eigen::Index r = 0; r < g.rows(); ++r) {
                if (std::abs(g(r, c)) > drop)
                    t.emplace_back(static_cast<int>(r), static_cast<int>(c), g(r, c));
            }
        }
        L.response.resize(static_cast<int>(g.rows()), static_cast<int>(g.cols()));
        L.response.setFromTriplets(t.begin(), t.end());
    }
}

bool AsyncRegions::Impl::solveSecondary(Layout& L, const double* borderValues, const Packet* loads,
                                        double* gammaOut, double* watchOut) noexcept {
    const auto begin = std::chrono::steady_clock::now();
    timespec cpu0{};
    clock_gettime(CLOCK_THREAD_CPUTIME_ID, &cpu0);
    const double cpuBegin =
        static_cast<double>(cpu0.tv_sec) + 1e-9 * static_cast<double>(cpu0.tv_nsec);
    const int unknowns = static_cast<int>(L.unknownCoarseDof.size());
    const Eigen::Index nb = static_cast<Eigen::Index>(L.borderDofs.size());
    int iterations = 0;
    bool ok = true;
    const int loadCount = loads != nullptr ? loads->loadCount : 0;
    const bool watching = watchOut != nullptr && L.interpWatch.rows() > 0;
    // Loads on secondary nodes need the whole field; otherwise Gamma (and the watched nodes)
    // alone when their responses to the border are at hand.
    const bool direct =
        L.gammaResponse.size() > 0 && loadCount == 0 && (!watching || L.watchResponse.size() > 0);
    if (direct) {
        // Quasi-static: Gamma = R u_B exactly (R from the factorisation, at set-up).
        for (Eigen::Index i = 0; i < nb; ++i) L.border[i] = borderValues[i];
        Eigen::Map<Eigen::VectorXd> out(gammaOut, L.gammaResponse.rows());
        out.noalias() = L.gammaResponse * L.border;
        ok = out.allFinite();
        if (watching) {
            Eigen::Map<Eigen::VectorXd> w(watchOut, L.watchResponse.rows());
            w.noalias() = L.watchResponse * L.border;
            ok = ok && w.allFinite();
        }
        L.fieldStale = true;
    } else if (unknowns > 0) {
        try {
            for (int i = 0; i < unknowns; ++i) {
                const int cd = L.unknownCoarseDof[sz(i)];
                L.x[i] = uC[cd];
                L.v[i] = vC[cd];
                L.a[i] = aC[cd];
            }
            for (Eigen::Index i = 0; i < nb; ++i) L.border[i] = borderValues[i];
            const bool dynamic = options.secondaryIntegrator != Integrator::quasiStatic;
            const double alpha = model.material().dampingAlpha;
            const double beta = model.material().dampingBeta;
            L.rhs.noalias() = -sK * (L.kcb * L.border);
            // External loads on secondary dofs, restricted with I^T (rows of P dofs are empty).
            for (int i = 0; i < loadCount; ++i) {
                const double f = loads->loadValues[sz(i)];
                for (RowMatrix::InnerIterator it(L.interp, loads->loadDofs[sz(i)]); it; ++it)
                    L.rhs[it.col()] += it.value() * f;
            }
            if (dynamic) {
                L.yc = nm.a1 * L.x + nm.a4 * L.v + nm.a5 * L.a;
                L.ym = nm.a0 * L.x + nm.a2 * L.v + nm.a3 * L.a + alpha * L.yc;
                L.rhs.noalias() += L.mc * L.ym;
                if (beta > 0.0) L.rhs.noalias() += beta * (L.kc * L.yc);
            }
            if (options.secondarySolver == LinearSolverKind::cholmod) {
                L.xNew = L.cholmod.solve(L.rhs);
            } else {
                // Warm-started Jacobi PCG, SpMV and dots on the arena's TBB threads.
                auto spmv = [&](const Eigen::VectorXd& in, Eigen::VectorXd& out) {
                    const RowMatrix& A = L.rowA;
                    parallelFor(tbb::blocked_range<int>(0, unknowns, 512),
                                [&](const tbb::blocked_range<int>& rg) {
                                    for (int i = rg.begin(); i != rg.end(); ++i)
                                        out[i] = A.row(i).dot(in);
                                });
                };
                auto dot = [&](const Eigen::VectorXd& x1, const Eigen::VectorXd& x2) {
                    return tbb::parallel_reduce(
                        tbb::blocked_range<Eigen::Index>(0, x1.size(), 4096), 0.0,
                        [&](const tbb::blocked_range<Eigen::Index>& rg, double s) {
                            const Eigen::Index len = rg.end() - rg.begin();
                            return s + x1.segment(rg.begin(), len).dot(x2.segment(rg.begin(), len));
                        },
                        [](double s1, double s2) { return s1 + s2; });
                };
                L.xNew = L.x;  // warm start: the previous solution
                const double bnorm = std::sqrt(dot(L.rhs, L.rhs));
                if (bnorm == 0.0) {
                    L.xNew.setZero();
                } else {
                    spmv(L.xNew, L.q);
                    L.r = L.rhs - L.q;
                    L.z = L.inverseDiagonal.cwiseProduct(L.r);
                    L.p = L.z;
                    double rz = dot(L.r, L.z);
                    const double tol = options.pcgRelativeTolerance * bnorm;
                    while (std::sqrt(dot(L.r, L.r)) > tol &&
                           iterations < options.pcgMaxIterations) {
                        spmv(L.p, L.q);
                        const double step = rz / dot(L.p, L.q);
                        L.xNew += step * L.p;
                        L.r -= step * L.q;
                        L.z = L.inverseDiagonal.cwiseProduct(L.r);
                        const double rzNew = dot(L.r, L.z);
                        L.p = L.z + (rzNew / rz) * L.p;
                        rz = rzNew;
                        ++iterations;
                    }
                }
            }
            ok = L.xNew.allFinite();
            if (ok) {
                if (dynamic) {
                    const double dt = periodSeconds;
                    if (options.secondaryIntegrator == Integrator::newmark) {
                        L.ym = nm.a0 * (L.xNew - L.x) - nm.a2 * L.v - nm.a3 * L.a;  // a(n+1)
                        L.v += dt * 0.5 * (L.a + L.ym);
                        L.a = L.ym;
                    } else {
                        L.ym = (L.xNew - L.x) / dt;  // v(n+1)
                        L.a = (L.ym - L.v) / dt;
                        L.v = L.ym;
                    }
                }
                for (int i = 0; i < unknowns; ++i) {
                    const int cd = L.unknownCoarseDof[sz(i)];
                    uC[cd] = L.xNew[i];
                    vC[cd] = L.v[i];
                    aC[cd] = L.a[i];
                }
                L.x = L.xNew;
                L.fieldStale = false;
            }
        } catch (...) {
            ok = false;
        }
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
    lastSolve.store(seconds, std::memory_order_relaxed);
    timespec cpu{};
    clock_gettime(CLOCK_THREAD_CPUTIME_ID, &cpu);
    const double cpuNow = static_cast<double>(cpu.tv_sec) + 1e-9 * static_cast<double>(cpu.tv_nsec);
    lastSolveCpu.store(cpuNow - cpuBegin, std::memory_order_relaxed);
    if (seconds > maxSolve.load(std::memory_order_relaxed))
        maxSolve.store(seconds, std::memory_order_relaxed);
    lastIterations.store(iterations, std::memory_order_relaxed);
    if (ok) solves.fetch_add(1, std::memory_order_release);
    return ok;
}

void AsyncRegions::Impl::secondaryLoop() {
    pinCurrentThread(options.secondaryCpu);
    arena->execute([this] {
        // `sec` is the layout the servo uses (or will, once it adopts `offered`).
        Layout* sec = layouts[0].get();
        Layout* offered = nullptr;
        // Contact changes: a builder thread (same CPU, lower priority) assembles and factorises
        // the new layout while this thread keeps solving the current one; this thread then adds
        // the entry state from its latest solution and offers the layout to the servo.
        enum : int { kIdle, kBuilding, kBuilt, kFailed };
        std::atomic<int> buildState{kIdle};
        std::unique_ptr<Layout> built;
        std::thread builder;
        int building = -1;
        auto buildBegin = std::chrono::steady_clock::now();
        while (!stop.load(std::memory_order_acquire)) {
            if (Layout* old = retired.exchange(nullptr, std::memory_order_acq_rel)) {
                sec = offered;
                offered = nullptr;
                delete old;
            }
            if (offered != nullptr || stalled.load(std::memory_order_acquire)) {
                std::this_thread::sleep_for(std::chrono::microseconds(50));
                continue;
            }
            const int state = buildState.load(std::memory_order_acquire);
            if (state == kBuilt || state == kFailed) {
                builder.join();
                buildState.store(kIdle, std::memory_order_relaxed);
                if (state == kBuilt) {
                    try {
                        finishForContact(*sec, *built, buildBegin);
                        offered = built.release();
                        pending.store(offered, std::memory_order_release);
                    } catch (...) {
                        rejected = building;
                    }
                } else {
                    rejected = building;  // e.g. a failed factorisation: keep the current layout
                }
                built.reset();
                continue;
            }
            const int want = requested.load(std::memory_order_acquire);
            if (state == kIdle && contactChangeWanted(*sec, want)) {
                building = want;
                buildBegin = std::chrono::steady_clock::now();
                buildState.store(kBuilding, std::memory_order_relaxed);
                const int seeds = sec->seeds;
                builder = std::thread([this, want, seeds, &built, &buildState] {
                    setpriority(PRIO_PROCESS, static_cast<id_t>(gettid()), 10);
                    try {
                        built = buildPrepared(want, seeds);
                        buildState.store(kBuilt, std::memory_order_release);
                    } catch (...) {
                        buildState.store(kFailed, std::memory_order_release);
                    }
                });
            }
            if (!snapshots.update()) {
                std::this_thread::sleep_for(std::chrono::microseconds(50));
                continue;
            }
            const Packet& in = snapshots.front();
            if (in.generation != sec->generation) continue;  // from before the last swap
            Packet& out = results.back();
            const std::size_t ng = sec->gammaDofs.size(), nb = sec->borderDofs.size();
            double* watchOut = wPrev.empty() ? nullptr : out.values.data() + ng + nb;
            if (solveSecondary(*sec, in.values.data(), &in, out.values.data(), watchOut)) {
                std::copy(in.values.begin(),
                          in.values.begin() + static_cast<std::ptrdiff_t>(sec->borderDofs.size()),
                          out.values.begin() + static_cast<std::ptrdiff_t>(sec->gammaDofs.size()));
                out.time = in.time;
                out.sequence = in.sequence;
                out.generation = sec->generation;
                results.publish();
            }
        }
        if (builder.joinable()) builder.join();
    });
}

void AsyncRegions::Impl::setGamma(const Layout& L, double* target, double t,
                                  bool product) noexcept {
    double frac = 1.0;
    if (options.interpolate) frac = std::clamp((t - gStart) / periodSeconds, 0.0, 1.0);
    const std::size_t n = L.gammaDofs.size();
    if (L.response.nonZeros() > 0) {
        const std::size_t nb = L.borderDofs.size();
        if (product) {
            for (std::size_t i = 0; i < nb; ++i) {
                const Eigen::Index k = static_cast<Eigen::Index>(i);
                bNow[k] = target[L.borderDofs[i]] - (bPrev[k] + frac * (bCur[k] - bPrev[k]));
            }
            gFix.head(static_cast<Eigen::Index>(n)).noalias() =
                L.response * bNow.head(static_cast<Eigen::Index>(nb));
        }
        for (std::size_t i = 0; i < n; ++i)
            target[L.gammaDofs[i]] =
                gPrev[i] + frac * (gCur[i] - gPrev[i]) + gFix[static_cast<Eigen::Index>(i)];
        return;
    }
    for (std::size_t i = 0; i < n; ++i)
        target[L.gammaDofs[i]] = gPrev[i] + frac * (gCur[i] - gPrev[i]);
}

void AsyncRegions::Impl::acceptSolution(const double* gamma, const double* border,
                                        const double* watch) noexcept {
    // Start from the value shown now, so a solution arriving mid-period does not jump.
    const Layout& L = *layouts[sz(current)];
    double frac = 1.0;
    if (options.interpolate) frac = std::clamp((time - gStart) / periodSeconds, 0.0, 1.0);
    for (std::size_t i = 0; i < L.gammaDofs.size(); ++i) {
        gPrev[i] = gPrev[i] + frac * (gCur[i] - gPrev[i]);
        gCur[i] = gamma[i];
    }
    for (std::size_t i = 0; i < L.borderDofs.size(); ++i) {
        const Eigen::Index k = static_cast<Eigen::Index>(i);
        bPrev[k] = bPrev[k] + frac * (bCur[k] - bPrev[k]);
        bCur[k] = border[i];
    }
    if (watch != nullptr) {
        for (std::size_t i = 0; i < wPrev.size(); ++i) {
            wPrev[i] = wPrev[i] + frac * (wCur[i] - wPrev[i]);
            wCur[i] = watch[i];
        }
    }
    gStart = time;
    used.fetch_add(1, std::memory_order_relaxed);
}

template <class F>
void AsyncRegions::Impl::forEachEnteringDof(const Layout& from, const Layout& to, F&& f) const {
    std::vector<std::uint8_t> known(from.isPrimary);
    for (int n : from.gammaNodes) known[sz(n)] = 1;
    auto enter = [&](int n) {
        if (known[sz(n)]) return;
        known[sz(n)] = 1;
        for (int k = 0; k < 3; ++k) {
            const int d = 3 * n + k;
            if (fixed[sz(d)]) continue;
            f(d, from.unknownCoarseDof.empty() ? 0.0 : from.interp.row(d).dot(from.x));
        }
    };
    for (int n : to.primaryNodes) enter(n);
    for (int n : to.gammaNodes) enter(n);
}

void AsyncRegions::Impl::seedWatched(const Layout& from) noexcept {
    // Called before sizeCoupling() restarts the interpolation clock. Watched nodes the servo
    // showed (P and Gamma of the layout being left) start from those values: the secondary's
    // last solution has nothing (zero) for primary nodes. The others restart their
    // interpolation from the value shown now (so they do not fall back to the previous
    // solution when the clock restarts) towards the same newest solution.
    const double frac = shownFraction();
    const std::vector<int>& watch = options.watchNodes;
    for (std::size_t i = 0; i < watch.size(); ++i) {
        const int n = watch[i];
        const bool shownByServo = from.isPrimary[sz(n)] || from.isGamma[sz(n)];
        for (std::size_t k = 0; k < 3; ++k) {
            const std::size_t j = 3 * i + k;
            if (shownByServo) {
                wPrev[j] = u[3 * n + static_cast<int>(k)];
                wCur[j] = wPrev[j];
            } else {
                wPrev[j] = wPrev[j] + frac * (wCur[j] - wPrev[j]);
            }
        }
    }
}

void AsyncRegions::Impl::primarySubsteps(const Eigen::Vector3d& target,
                                         AsyncTickResult& result) noexcept {
    const Layout& L = *layouts[sz(current)];
    const double* ke = model.unitStiffness();
    const Eigen::Map<const Eigen::Matrix<double, 24, 24>, Eigen::Aligned64> K(ke);
    const double beta = model.material().dampingBeta;
    const double dt = dtSub;
    const double dt2 = dt * dt;
    const std::vector<int>& contactDofs = L.contactDofs;
    for (std::size_t i = 0; i < contactDofs.size(); ++i)
        contactStart[static_cast<Eigen::Index>(i)] = u[contactDofs[i]];
    for (int s = 0; s < substeps; ++s) {
        const bool product = s == 0 || !options.condensedOncePerTick;
        setGamma(L, u.data(), time, product);
        const double* operand = u.data();
        if (beta > 0.0) {
            setGamma(L, uPrev.data(), time - dt, product);
            const double b = beta / dt;
            for (int d : L.touchedDofs) work[d] = u[d] + b * (u[d] - uPrev[d]);
            operand = work.data();
        }
        for (int d : L.touchedDofs) fInt[d] = 0.0;
        const std::size_t cells = L.cellDofs.size();
        for (std::size_t c = 0; c < cells; ++c) {
            const std::array<int, 8>& nd = L.cellDofs[c];
            Eigen::Matrix<double, 24, 1> ue;
            for (int a = 0; a < 8; ++a) {
                for (int k = 0; k < 3; ++k) ue[3 * a + k] = operand[nd[sz(a)] + k];
            }
            const Eigen::Matrix<double, 24, 1> fe = L.cellE[c] * (K * ue);
            for (int a = 0; a < 8; ++a) {
                for (int k = 0; k < 3; ++k) fInt[nd[sz(a)] + k] += fe[3 * a + k];
            }
        }
        for (int d : L.freeDofs)
            uPrev[d] = (dt2 * (fExt[d] - fInt[d]) + twoMass[d] * u[d] - prevCoef[d] * uPrev[d]) *
                       invDen[d];
        const double frac = static_cast<double>(s + 1) / substeps;
        for (std::size_t i = 0; i < contactDofs.size(); ++i) {
            const double start = contactStart[static_cast<Eigen::Index>(i)];
            uPrev[contactDofs[i]] =
                start + frac * (target[static_cast<Eigen::Index>(i % 3)] - start);
        }
        u.swap(uPrev);
        time += dt;
        ++result.substeps;
    }
    // Gamma as of now (with the tick's last condensed correction), for nodeDisplacement(); the
    // next substep sets it again before using it.
    setGamma(L, u.data(), time, false);
    bool finite = true;
    for (int d : L.freeDofs) finite = finite && std::isfinite(u[d]);
    if (!finite) {
        for (int d : L.freeDofs) {
            u[d] = 0.0;
            uPrev[d] = 0.0;
        }
        result.flags |= kStepDiverged;
    }
    Eigen::Vector3d force = Eigen::Vector3d::Zero();
    for (std::size_t i = 0; i < contactDofs.size(); ++i)
        force[static_cast<Eigen::Index>(i % 3)] += fInt[contactDofs[i]];
    if (!forceDrive) result.contactForce = finite ? force : Eigen::Vector3d::Zero();
}

void AsyncRegions::Impl::switchLayout(int next) {
    Layout& oldL = *layouts[sz(current)];
    Layout& newL = *layouts[sz(next)];
    refreshField(oldL);
    // The border as the primary sees it now (current and previous substep): border nodes that
    // enter the primary keep that motion; deeper nodes take the secondary's solution at rest.
    setGamma(oldL, u.data(), time, true);
    setGamma(oldL, uPrev.data(), time - dtSub, true);
    seedWatched(oldL);
    forEachEnteringDof(oldL, newL, [&](int d, double value) {
        u[d] = value;
        uPrev[d] = value;
    });
    // Coarse unknowns leaving the primary take the primary's values.
    const HexMesh& mesh = model.mesh();
    for (int cd : newL.unknownCoarseDof) {
        const int cn = cd / 3, k = cd % 3;
        const int X = cn % coarseCounts[0], Y = (cn / coarseCounts[0]) % coarseCounts[1],
                  Z = cn / (coarseCounts[0] * coarseCounts[1]);
        const int fine = mesh.node(X * lod, Y * lod, Z * lod);
        if (!oldL.isPrimary[sz(fine)]) continue;
        const int d = 3 * fine + k;
        uC[cd] = u[d];
        vC[cd] = (u[d] - uPrev[d]) / dtSub;
        aC[cd] = 0.0;
    }
    const int unknowns = static_cast<int>(newL.unknownCoarseDof.size());
    for (int i = 0; i < unknowns; ++i) {
        const int cd = newL.unknownCoarseDof[sz(i)];
        newL.x[i] = uC[cd];
        newL.v[i] = vC[cd];
        newL.a[i] = aC[cd];
    }
    current = next;
    sizeCoupling(newL);
    // Condensed coupling: restart from the shown Gamma, consistent with the shown border (the
    // correction G (u_B - u~_B) starts at zero). Plain coupling: from the secondary's solution.
    if (options.condensed) return;
    const Eigen::Index ng = static_cast<Eigen::Index>(newL.gammaDofs.size());
    Eigen::Map<Eigen::VectorXd> g(gPrev.data(), ng);
    if (unknowns > 0) {
        g.noalias() = newL.interpGamma * newL.x;
    } else {
        g.setZero();
    }
    std::copy(gPrev.begin(), gPrev.begin() + ng, gCur.begin());
}

AsyncRegions::AsyncRegions(const FemModel& model, const Constraints& constraints,
                           std::vector<int> contactNodes, const AsyncRegionsOptions& options)
    : mImpl(std::make_unique<Impl>(model, constraints, std::move(contactNodes), options)) {}

AsyncRegions::~AsyncRegions() = default;

void AsyncRegions::Impl::takeLoads(std::span<const NodalLoad> loads,
                                   AsyncTickResult& result) noexcept {
    const Layout& L = *layouts[sz(current)];
    const HexMesh& mesh = model.mesh();
    Eigen::Vector3d sum = Eigen::Vector3d::Zero();
    std::size_t taken = 0;
    for (std::size_t i = 0; i < loads.size(); ++i) {
        if (taken >= sz(options.maxLoads)) {  // bounded work whatever the caller passes
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
            if (fixed[sz(d)]) continue;  // taken by the support
            if (primary) {
                fExtDofs[fExtCount++] = d;  // a repeated dof is listed twice: harmless
                fExt[d] += load.force[k];
            } else {
                fAcc[d] += load.force[k];
                if (!accMark[sz(n)]) {
                    accMark[sz(n)] = 1;
                    accNodes[accCount++] = n;
                }
            }
        }
    }
    result.contactForce = sum;
    if (result.loadsRefused > 0) result.flags |= kAsyncLoadsRefused;
}

void AsyncRegions::Impl::packLoads(Packet& out) noexcept {
    // The period's mean load on each secondary dof (its impulse over the period).
    const double inv = 1.0 / period;
    int count = 0;
    for (std::size_t i = 0; i < accCount; ++i) {
        const int n = accNodes[i];
        accMark[sz(n)] = 0;
        for (int k = 0; k < 3; ++k) {
            const int d = 3 * n + k;
            const double f = fAcc[d];
            fAcc[d] = 0.0;
            if (f == 0.0) continue;
            out.loadDofs[sz(count)] = d;
            out.loadValues[sz(count)] = f * inv;
            ++count;
        }
    }
    accCount = 0;
    out.loadCount = count;
}

AsyncTickResult AsyncRegions::tick(const Eigen::Vector3d& contactDisplacement) noexcept {
    if (mImpl->forceDrive) {
        AsyncTickResult r;
        r.flags |= kStepBadForce;
        return r;
    }
    return mImpl->advance(contactDisplacement, {});
}

AsyncTickResult AsyncRegions::tick(std::span<const NodalLoad> loads) noexcept {
    if (!mImpl->forceDrive) {
        AsyncTickResult r;
        r.flags |= kStepBadForce;
        return r;
    }
    return mImpl->advance(Eigen::Vector3d::Zero(), loads);
}

AsyncTickResult AsyncRegions::Impl::advance(const Eigen::Vector3d& contactDisplacement,
                                            std::span<const NodalLoad> loads) noexcept {
    Impl& m = *this;
    AsyncTickResult result;
    if (m.options.threaded) {
        // A layout prepared for a new contact: one pointer exchange, state hand-over over the
        // primary's nodes, and the old layout goes back to the secondary thread for deletion.
        if (Layout* next = m.pending.exchange(nullptr, std::memory_order_acq_rel)) {
            m.adoptLayout(*m.layouts[0], *next);
            Layout* old = m.layouts[0].release();
            m.layouts[0].reset(next);
            m.retired.store(old, std::memory_order_release);
            result.layoutChanged = true;
        }
        if (m.results.update()) {
            const Packet& in = m.results.front();
            const Layout& L = *m.layouts[0];
            if (in.generation == L.generation) {
                const std::size_t ng = L.gammaDofs.size(), nb = L.borderDofs.size();
                m.acceptSolution(in.values.data(), in.values.data() + ng,
                                 m.wPrev.empty() ? nullptr : in.values.data() + ng + nb);
                result.secondaryUpdated = true;
            }
        }
    }
    if (m.forceDrive) m.takeLoads(loads, result);
    const std::vector<int>& contactDofs = m.layouts[sz(m.current)]->contactDofs;
    Eigen::Vector3d target = contactDisplacement;
    if (!m.forceDrive && !target.allFinite()) {
        target = Eigen::Vector3d(m.u[contactDofs[0]], m.u[contactDofs[1]], m.u[contactDofs[2]]);
        result.flags |= kStepBadForce;
    }
    m.primarySubsteps(target, result);
    for (std::size_t i = 0; i < m.fExtCount; ++i) m.fExt[m.fExtDofs[i]] = 0.0;
    m.fExtCount = 0;
    {
        const int c = m.layouts[sz(m.current)]->contactNodes[0];
        result.contactDisplacement = m.u.segment<3>(3 * c);
    }
    ++m.ticks;
    if (m.ticks % static_cast<std::uint64_t>(m.period) != 0) return result;

    if (m.options.threaded) {
        const Layout& L = *m.layouts[sz(m.current)];
        Packet& out = m.snapshots.back();
        for (std::size_t i = 0; i < L.borderDofs.size(); ++i) out.values[i] = m.u[L.borderDofs[i]];
        m.packLoads(out);
        out.time = m.time;
        out.sequence = m.ticks;
        out.generation = L.generation;
        m.snapshots.publish();
        return result;
    }
    // Synchronous: change the contact, adapt the layout, then solve the secondary inline.
    const int want = m.requested.load(std::memory_order_relaxed);
    if (m.contactChangeWanted(*m.layouts[sz(m.current)], want)) {
        try {
            std::vector<std::unique_ptr<Layout>> next(m.layouts.size());
            for (std::size_t k = 0; k < next.size(); ++k) {
                if (k == sz(m.current)) {
                    next[k] = m.prepareForContact(*m.layouts[k], want, m.layouts[k]->seeds);
                } else {
                    next[k] = m.buildLayout({want}, m.layouts[k]->seeds);
                    m.arena->execute([&] { m.prepareSolver(*next[k]); });
                }
            }
            m.adoptLayout(*m.layouts[sz(m.current)], *next[sz(m.current)]);
            m.layouts = std::move(next);
            result.layoutChanged = true;
        } catch (...) {
            m.rejected = want;
        }
    }
    if (m.layouts.size() > 1) {
        const double strain = (m.forceDrive ? result.contactDisplacement.norm() : target.norm()) /
                              m.options.strainReferenceLength;
        const int levels = static_cast<int>(m.layouts.size());
        const int level = static_cast<int>(
            std::lround(std::clamp(strain / m.options.strainAtMax, 0.0, 1.0) * (levels - 1)));
        if (level != m.current) m.switchLayout(level);
    }
    Layout& L = *m.layouts[sz(m.current)];
    Packet& in = m.snapshots.slot(0);
    std::vector<double>& border = in.values;
    double* gamma = m.results.slot(0).values.data();
    double* watch = m.wPrev.empty() ? nullptr : gamma + m.model.dofCount();
    for (std::size_t i = 0; i < L.borderDofs.size(); ++i) border[i] = m.u[L.borderDofs[i]];
    m.packLoads(in);
    bool ok = false;
    m.arena->execute([&] { ok = m.solveSecondary(L, border.data(), &in, gamma, watch); });
    if (ok) {
        m.acceptSolution(gamma, border.data(), watch);
        result.secondaryUpdated = true;
    }
    return result;
}

const std::vector<int>& AsyncRegions::primaryNodes() const {
    return mImpl->layouts[sz(mImpl->current)]->primaryNodes;
}
int AsyncRegions::primaryFreeNodeCount() const {
    return mImpl->layouts[sz(mImpl->current)]->freeNodeCount;
}
const std::vector<int>& AsyncRegions::secondaryBorderNodes() const {
    return mImpl->layouts[sz(mImpl->current)]->gammaNodes;
}
int AsyncRegions::primaryCellCount() const {
    return static_cast<int>(mImpl->layouts[sz(mImpl->current)]->cellDofs.size());
}
int AsyncRegions::secondaryDofCount() const {
    return static_cast<int>(mImpl->layouts[sz(mImpl->current)]->unknownCoarseDof.size());
}
int AsyncRegions::layoutIndex() const { return mImpl->current; }
const std::vector<int>& AsyncRegions::contactNodes() const {
    return mImpl->layouts[sz(mImpl->current)]->contactNodes;
}

bool AsyncRegions::requestContactNode(int node) noexcept {
    const HexMesh& mesh = mImpl->model.mesh();
    if (node < 0 || node >= mesh.nodeCount() || !mesh.nodeActive()[sz(node)]) return false;
    mImpl->requested.store(node, std::memory_order_release);
    return true;
}
int AsyncRegions::periodTicks() const { return mImpl->period; }
double AsyncRegions::substepSeconds() const { return mImpl->dtSub; }
double AsyncRegions::time() const { return mImpl->time; }

Eigen::VectorXd AsyncRegions::displacement() const {
    Impl& m = *mImpl;
    Layout& L = *m.layouts[sz(m.current)];
    if (!m.options.threaded) m.refreshField(L);
    Eigen::VectorXd out = m.u;
    if (m.options.threaded) {  // the secondary's field is its thread's: the watched nodes only
        for (int n : m.options.watchNodes) out.segment<3>(3 * n) = nodeDisplacement(n);
    }
    if (!m.options.threaded && !L.unknownCoarseDof.empty()) {
        const Eigen::VectorXd s = L.interp * L.x;
        for (int n = 0; n < m.model.mesh().nodeCount(); ++n) {
            if (L.isPrimary[sz(n)]) continue;
            for (int k = 0; k < 3; ++k) {
                const int d = 3 * n + k;
                if (!m.fixed[sz(d)]) out[d] = s[d];
            }
        }
    }
    return out;
}

Eigen::Vector3d AsyncRegions::Impl::shown(const Layout& L, int node, double frac) const noexcept {
    const std::size_t n = sz(node);
    if (L.isPrimary[n] || L.isGamma[n]) return u.segment<3>(3 * node);
    const int w = watchIndex[n];
    Eigen::Vector3d out = Eigen::Vector3d::Constant(std::numeric_limits<double>::quiet_NaN());
    const bool active = model.mesh().nodeActive()[n];
    for (int k = 0; k < 3; ++k) {
        const int d = 3 * node + k;
        if (fixed[sz(d)] || !active) {
            out[k] = u[d];
        } else if (w >= 0) {
            const std::size_t i = 3 * sz(w) + sz(k);
            out[k] = wPrev[i] + frac * (wCur[i] - wPrev[i]);
        }
    }
    return out;
}

double AsyncRegions::Impl::shownFraction() const noexcept {
    return options.interpolate ? std::clamp((time - gStart) / periodSeconds, 0.0, 1.0) : 1.0;
}

Eigen::Vector3d AsyncRegions::nodeDisplacement(int node) const noexcept {
    const Impl& m = *mImpl;
    if (node < 0 || node >= m.model.mesh().nodeCount())
        return Eigen::Vector3d::Constant(std::numeric_limits<double>::quiet_NaN());
    return m.shown(*m.layouts[sz(m.current)], node, m.shownFraction());
}

std::size_t AsyncRegions::watchedDisplacements(std::span<Eigen::Vector3d> out) const noexcept {
    const Impl& m = *mImpl;
    const std::vector<int>& watch = m.options.watchNodes;
    const std::size_t count = std::min(out.size(), watch.size());
    const Layout& L = *m.layouts[sz(m.current)];
    const double frac = m.shownFraction();
    for (std::size_t i = 0; i < count; ++i) out[i] = m.shown(L, watch[i], frac);
    return count;
}

const std::vector<int>& AsyncRegions::watchNodes() const { return mImpl->options.watchNodes; }

AsyncSecondaryStats AsyncRegions::secondaryStats() const {
    const Impl& m = *mImpl;
    AsyncSecondaryStats s;
    s.solves = m.solves.load(std::memory_order_acquire);
    s.used = m.used.load(std::memory_order_relaxed);
    s.lastSolveSeconds = m.lastSolve.load(std::memory_order_relaxed);
    s.maxSolveSeconds = m.maxSolve.load(std::memory_order_relaxed);
    s.lastSolveCpuSeconds = m.lastSolveCpu.load(std::memory_order_relaxed);
    s.lastIterations = m.lastIterations.load(std::memory_order_relaxed);
    s.layoutsPrepared = m.prepared.load(std::memory_order_acquire);
    s.lastPrepareSeconds = m.lastPrepare.load(std::memory_order_relaxed);
    return s;
}

void AsyncRegions::setSecondaryStalledForTest(bool stalled) noexcept {
    mImpl->stalled.store(stalled, std::memory_order_release);
}

}  // namespace palp::fem
