// AsyncRegions: the facade over the parts of the asynchronous regions, cut along the thread
// that owns each part's state:
//   AsyncSetup       (async_setup.h)       validated options and fixed data; read-only, shared.
//   LayoutBuilder    (layout_builder.h)    builds and factorises layouts; const, any thread.
//   PrimaryRegion    (primary_region.h)    explicit primary; servo thread.
//   SecondaryRegion  (secondary_region.h)  implicit secondary; the secondary thread (threaded)
//                                          or the servo's period boundary (synchronous).
//   SecondaryThread  (secondary_thread.h)  threaded mode's secondary loop and layout builds.
//   BorderExchange, LayoutChannel          what crosses between servo and secondary: two
//                                          palp::TripleBuffers of border data, and the layout
//                                          hand-over (atomic pointer exchanges).
// The facade owns them, orders the servo tick and runs the synchronous period boundary.
#include "palp/fem/async_regions.h"

#include <tbb/task_arena.h>

#include <algorithm>
#include <cmath>
#include <limits>

#include "index_cast.h"
#include "palp/base/parallel.h"
#include "regions/async_layout.h"
#include "regions/async_setup.h"
#include "regions/layout_builder.h"
#include "regions/primary_region.h"
#include "regions/secondary_region.h"
#include "regions/secondary_thread.h"

namespace palp::fem {

/// @par Threading  The servo thread owns everything here but the secondary's parts: `secondary`
/// and the secondary work state of the layouts belong to the secondary thread in threaded mode
/// (to the servo thread at its period boundaries in synchronous mode). `layouts` and `current`
/// are the servo's; the secondary thread holds its own pointer to the layout in use, which
/// changes only through `channel`. The thread is declared last, so it is joined before any part
/// it uses is destroyed.
struct AsyncRegions::Impl {
    Impl(const FemModel& model, const Constraints& constraints, std::vector<int> contactNodes,
         const AsyncRegionsOptions& options);

    AsyncTickResult advance(const Eigen::Vector3d& contactDisplacement,
                            std::span<const NodalLoad> loads,
                            const CouplingSpring* spring = nullptr) noexcept;
    void exchangeWithSecondary(AsyncTickResult& result) noexcept;
    void publishSnapshot() noexcept;
    void periodBoundary(const Eigen::Vector3d& target, AsyncTickResult& result) noexcept;
    void changeContact(int want, AsyncTickResult& result) noexcept;
    void adaptLayout(const Eigen::Vector3d& target, const AsyncTickResult& result);
    void switchLayout(int next);
    void solveInline(AsyncTickResult& result) noexcept;
    Layout& layout() const noexcept { return *layouts[sz(current)]; }

    AsyncSetup setup;
    LayoutBuilder builder;
    tbb::task_arena arena;
    PrimaryRegion primary;
    SecondaryRegion secondary;
    BorderExchange exchange;
    LayoutChannel channel;
    std::vector<std::unique_ptr<Layout>> layouts;  // one, or one per adaptive size
    int current = 0;
    std::uint64_t ticks = 0;
    std::uint64_t lastSolutionTick = 0;       // threaded: the tick the newest solution entered at
    std::uint64_t staleTicks = 0;             // kAsyncSecondaryStaleSeconds in ticks
    std::unique_ptr<SecondaryThread> thread;  // threaded mode
};

AsyncRegions::Impl::Impl(const FemModel& model, const Constraints& constraints,
                         std::vector<int> contactNodes, const AsyncRegionsOptions& options)
    : setup(model, constraints, contactNodes, options),
      builder(setup, contactNodes),
      arena(options.secondaryThreads),
      primary(setup, constraints, contactNodes),
      secondary(setup),
      exchange(model.dofCount(), 3 * options.watchNodes.size()),
      staleTicks(static_cast<std::uint64_t>(
          std::ceil(kAsyncSecondaryStaleSeconds / setup.options.tickSeconds))) {
    // Layouts: one, or adaptiveLevels sizes from primaryNodes to maxPrimaryNodes.
    const AsyncRegionsOptions& o = setup.options;
    const int levels = setup.adaptive ? o.adaptiveLevels : 1;
    for (int k = 0; k < levels; ++k) {
        const int seeds =
            levels == 1
                ? o.primaryNodes
                : o.primaryNodes + static_cast<int>(std::lround(
                                       static_cast<double>(k) *
                                       (o.maxPrimaryNodes - o.primaryNodes) / (levels - 1)));
        layouts.push_back(builder.build(contactNodes, seeds));
        arenaExecute(arena, [&] { builder.prepare(*layouts.back()); });
    }
    primary.restartCoupling(*layouts[0]);
    if (o.threaded)
        thread = std::make_unique<SecondaryThread>(setup, builder, secondary, exchange, channel,
                                                   *layouts[0], arena);
}

AsyncRegions::AsyncRegions(const FemModel& model, const Constraints& constraints,
                           std::vector<int> contactNodes, const AsyncRegionsOptions& options)
    : mImpl(std::make_unique<Impl>(model, constraints, std::move(contactNodes), options)) {}

AsyncRegions::~AsyncRegions() = default;

AsyncTickResult AsyncRegions::tick(const Eigen::Vector3d& contactDisplacement) noexcept {
    if (mImpl->setup.forceDrive) {
        AsyncTickResult r;
        r.flags |= kStepBadForce;
        return r;
    }
    return mImpl->advance(contactDisplacement, {});
}

AsyncTickResult AsyncRegions::tick(std::span<const NodalLoad> loads) noexcept {
    if (!mImpl->setup.forceDrive) {
        AsyncTickResult r;
        r.flags |= kStepBadForce;
        return r;
    }
    return mImpl->advance(Eigen::Vector3d::Zero(), loads);
}

AsyncTickResult AsyncRegions::tick(std::span<const NodalLoad> loads,
                                   const CouplingSpring& spring) noexcept {
    if (!mImpl->setup.forceDrive) {
        AsyncTickResult r;
        r.flags |= kStepBadForce;
        return r;
    }
    return mImpl->advance(Eigen::Vector3d::Zero(), loads, &spring);
}

AsyncTickResult AsyncRegions::Impl::advance(const Eigen::Vector3d& contactDisplacement,
                                            std::span<const NodalLoad> loads,
                                            const CouplingSpring* spring) noexcept {
    AsyncTickResult result;
    if (setup.options.threaded) {
        exchangeWithSecondary(result);
        if (result.secondaryUpdated) lastSolutionTick = ticks;
        if (ticks - lastSolutionTick > staleTicks) result.flags |= kAsyncSecondaryStale;
    }
    if (setup.forceDrive) primary.takeLoads(layout(), loads, result);
    const std::vector<int>& contactDofs = layout().contactDofs;
    Eigen::Vector3d target = contactDisplacement;
    if (!setup.forceDrive && !target.allFinite()) {
        const Eigen::VectorXd& u = primary.u();
        target = Eigen::Vector3d(u[contactDofs[0]], u[contactDofs[1]], u[contactDofs[2]]);
        result.flags |= kStepBadForce;
    }
    primary.advance(layout(), target, spring, result);
    primary.clearTickLoads();
    result.contactDisplacement = primary.u().segment<3>(3 * layout().contactNodes[0]);
    ++ticks;
    if (ticks % static_cast<std::uint64_t>(setup.period) != 0) return result;
    if (setup.options.threaded) {
        publishSnapshot();
    } else {
        periodBoundary(target, result);
    }
    return result;
}

void AsyncRegions::Impl::exchangeWithSecondary(AsyncTickResult& result) noexcept {
    // A layout prepared for a new contact: one pointer exchange, state hand-over over the
    // primary's nodes, and the old layout goes back to the secondary thread for deletion.
    if (Layout* next = channel.pending.exchange(nullptr, std::memory_order_acq_rel)) {
        primary.adopt(*layouts[0], *next);
        Layout* old = layouts[0].release();
        layouts[0].reset(next);
        channel.retired.store(old, std::memory_order_release);
        result.layoutChanged = true;
        // The new layout's secondary solves at once (not at the next period boundary): a
        // layout adopted just after a boundary would run a whole period on its entry state.
        publishSnapshot();
    }
    if (exchange.results.update()) {
        const BorderPacket& in = exchange.results.front().value;
        const Layout& L = *layouts[0];
        if (in.generation == L.generation) {
            const std::size_t ng = L.gammaDofs.size(), nb = L.borderDofs.size();
            primary.acceptSolution(
                L, in.values.data(), in.values.data() + ng,
                setup.options.watchNodes.empty() ? nullptr : in.values.data() + ng + nb,
                in.sequence);
            result.secondaryUpdated = true;
        }
    }
}

void AsyncRegions::Impl::publishSnapshot() noexcept {
    const Layout& L = layout();
    BorderPacket& out = exchange.snapshots.back().value;
    primary.readBorder(L, out.values.data());
    primary.packLoads(out, ticks);
    out.time = primary.time();
    out.sequence = ticks;
    out.generation = L.generation;
    exchange.snapshots.publish();
}

void AsyncRegions::Impl::periodBoundary(const Eigen::Vector3d& target,
                                        AsyncTickResult& result) noexcept {
    // Synchronous: change the contact, adapt the layout, then solve the secondary inline.
    const int want = channel.requested.load(std::memory_order_relaxed);
    if (channel.wanted(layout(), want)) changeContact(want, result);
    adaptLayout(target, result);
    solveInline(result);
}

void AsyncRegions::Impl::changeContact(int want, AsyncTickResult& result) noexcept {
    try {
        std::vector<std::unique_ptr<Layout>> next(layouts.size());
        for (std::size_t k = 0; k < next.size(); ++k) {
            if (k == sz(current)) {
                const auto begin = std::chrono::steady_clock::now();
                next[k] = builder.buildPrepared(want, layouts[k]->seeds);
                secondary.prepareEntry(*layouts[k], *next[k], begin);
            } else {
                next[k] = builder.build({want}, layouts[k]->seeds);
                arenaExecute(arena, [&] { builder.prepare(*next[k]); });
            }
        }
        primary.adopt(layout(), *next[sz(current)]);
        layouts = std::move(next);
        result.layoutChanged = true;
    } catch (...) {
        channel.rejected = want;
    }
}

void AsyncRegions::Impl::adaptLayout(const Eigen::Vector3d& target, const AsyncTickResult& result) {
    if (layouts.size() <= 1) return;
    const AsyncRegionsOptions& o = setup.options;
    const double strain = (setup.forceDrive ? result.contactDisplacement.norm() : target.norm()) /
                          o.strainReferenceLength;
    const int levels = static_cast<int>(layouts.size());
    const int level =
        static_cast<int>(std::lround(std::clamp(strain / o.strainAtMax, 0.0, 1.0) * (levels - 1)));
    if (level != current) switchLayout(level);
}

void AsyncRegions::Impl::switchLayout(int next) {
    Layout& oldL = layout();
    Layout& newL = *layouts[sz(next)];
    secondary.refreshField(oldL);
    // The border as the primary sees it now (current and previous substep): border nodes that
    // enter the primary keep that motion; deeper nodes take the secondary's solution at rest.
    primary.showBorder(oldL);
    forEachEnteringDof(oldL, newL, setup.fixed,
                       [&](int d, double value) { primary.enter(d, value); });
    secondary.takeFromPrimary(oldL, newL, primary.u(), primary.uPrev(), primary.substepSeconds());
    current = next;
    primary.restartCoupling(newL);
    // Condensed coupling: restart from the shown Gamma, consistent with the shown border (the
    // correction G (u_B - u~_B) starts at zero). Plain coupling: from the secondary's solution.
    if (!setup.options.condensed) primary.restartGammaFrom(newL, newL.x);
}

void AsyncRegions::Impl::solveInline(AsyncTickResult& result) noexcept {
    // The exchange's back slots serve as work buffers (nothing is published in this mode).
    Layout& L = layout();
    BorderPacket& in = exchange.snapshots.back().value;
    double* border = in.values.data();
    double* gamma = exchange.results.back().value.values.data();
    double* watch = setup.options.watchNodes.empty() ? nullptr : gamma + setup.model.dofCount();
    primary.readBorder(L, border);
    primary.packLoads(in, ticks);
    bool ok = false;
    arenaExecute(arena, [&] { ok = secondary.solve(L, border, &in, gamma, watch); });
    if (ok) {
        primary.acceptSolution(L, gamma, border, watch, ticks);
        result.secondaryUpdated = true;
    }
}

const std::vector<int>& AsyncRegions::primaryNodes() const { return mImpl->layout().primaryNodes; }
int AsyncRegions::primaryFreeNodeCount() const { return mImpl->layout().freeNodeCount; }
const std::vector<int>& AsyncRegions::secondaryBorderNodes() const {
    return mImpl->layout().gammaNodes;
}
int AsyncRegions::primaryCellCount() const {
    return static_cast<int>(mImpl->layout().cellDofs.size());
}
int AsyncRegions::secondaryDofCount() const {
    const Layout& L = mImpl->layout();
    if (L.global != nullptr) return L.secondaryUnknowns;
    return static_cast<int>(L.unknownCoarseDof.size());
}
int AsyncRegions::layoutIndex() const { return mImpl->current; }
const std::vector<int>& AsyncRegions::contactNodes() const { return mImpl->layout().contactNodes; }

bool AsyncRegions::requestContactNode(int node) noexcept {
    const HexMesh& mesh = mImpl->setup.model.mesh();
    if (node < 0 || node >= mesh.nodeCount() || !mesh.nodeActive()[sz(node)]) return false;
    mImpl->channel.requested.store(node, std::memory_order_release);
    return true;
}
int AsyncRegions::periodTicks() const { return mImpl->setup.period; }
double AsyncRegions::substepSeconds() const { return mImpl->primary.substepSeconds(); }
double AsyncRegions::time() const { return mImpl->primary.time(); }

Eigen::VectorXd AsyncRegions::displacement() const {
    Impl& m = *mImpl;
    Layout& L = m.layout();
    const bool threaded = m.setup.options.threaded;
    if (!threaded) m.secondary.refreshField(L);
    Eigen::VectorXd out = m.primary.u();
    if (threaded) {  // the secondary's field is its thread's: the watched nodes only
        for (int n : m.setup.options.watchNodes) out.segment<3>(3 * n) = nodeDisplacement(n);
    }
    if (!threaded && !L.unknownCoarseDof.empty()) {
        const Eigen::VectorXd s = L.interp * L.x;
        for (int n = 0; n < m.setup.model.mesh().nodeCount(); ++n) {
            if (L.isPrimary[sz(n)]) continue;
            for (int k = 0; k < 3; ++k) {
                const int d = 3 * n + k;
                if (!m.setup.fixed[sz(d)]) out[d] = s[d];
            }
        }
    }
    return out;
}

Eigen::Vector3d AsyncRegions::nodeDisplacement(int node) const noexcept {
    const Impl& m = *mImpl;
    if (node < 0 || node >= m.setup.model.mesh().nodeCount())
        return Eigen::Vector3d::Constant(std::numeric_limits<double>::quiet_NaN());
    return m.primary.shown(m.layout(), node, m.primary.shownFraction());
}

std::size_t AsyncRegions::watchedDisplacements(std::span<Eigen::Vector3d> out) const noexcept {
    const Impl& m = *mImpl;
    const std::size_t count = std::min(out.size(), m.setup.options.watchNodes.size());
    m.primary.shownWatched(m.layout(), m.primary.shownFraction(), out.first(count));
    return count;
}

std::size_t AsyncRegions::watchedDisplacements(std::size_t first,
                                               std::span<Eigen::Vector3d> out) const noexcept {
    const Impl& m = *mImpl;
    return m.primary.shownWatched(m.layout(), m.primary.shownFraction(), first, out);
}

WatchedChanges AsyncRegions::watchedChanges(std::size_t first, std::size_t count,
                                            std::span<const double> shown, double still,
                                            std::span<std::uint32_t> index,
                                            std::span<Eigen::Vector3d> out) const noexcept {
    const Impl& m = *mImpl;
    return m.primary.changedWatched(m.layout(), m.primary.shownFraction(), first, count, shown,
                                    still, index, out);
}

const std::vector<int>& AsyncRegions::watchNodes() const { return mImpl->setup.options.watchNodes; }

AsyncSecondaryStats AsyncRegions::secondaryStats() const {
    return mImpl->secondary.stats(mImpl->primary.used());
}

int AsyncRegions::slideZoneDofs(const FemModel& model, const Constraints& constraints,
                                const std::vector<int>& contactNodes,
                                const AsyncRegionsOptions& options) {
    const AsyncSetup setup(model, constraints, contactNodes, options);
    return 3 * static_cast<int>(LayoutBuilder::zoneCoarseNodes(setup, contactNodes).size());
}

void AsyncRegions::setSecondaryStalledForTest(bool stalled) noexcept {
    if (mImpl->thread) mImpl->thread->setStalled(stalled);
}

void AsyncRegions::setBuildDelayForTest(double seconds) noexcept {
    if (mImpl->thread) mImpl->thread->setBuildDelay(seconds);
}

}  // namespace palp::fem
