// bench_async threaded: the servo thread pinned to CPU 0 ticks at 1 kHz wall clock (sleeping to
// the next deadline), the secondary pinned to CPU 1; with --move MS the contact moves and the
// whole mesh, stepped explicitly every tick with the same input, is the reference.
//
// --contact slide (the default): a finger sliding continuously over the top face, as palp's
// DeformableBody couples it. The contact point moves along +x at one node (5 mm) per MS ms
// (50 mm/s at --move 100), back and forth between x = 1 and x = size - 2; a coupling spring
// (fem::CouplingSpring, --k N/m, contact damper --damping-ratio of critical) pulls the
// Gaussian-filtered displacement of the top nodes under the point (sigma --filter-mm, cutoff
// 3 sigma; 0: linear weights on the two nodes either side) down to the press depth, with no
// tangential force (the target's x and y are the filtered point's own at the tick's start).
// The regions (30 seeds unless --n, the top face watched unless --watch 0, as a DeformableBody
// has them) get tick(loads, spring); the reference ExplicitSolver::step(dt, spring) with the
// same spring. The regions are asked for the node nearest the point --lead ms ahead.
// --contact jump: the driven node jumps one node along +x every MS ms (wrapping to x = 1), the
// reference switching at the same ticks: the abrupt worse case.
#include "bench_async_slide.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <thread>
#include <vector>

#include "async_problem.h"
#include "palp/base/thread.h"
#include "palp/fem/coupling_spring.h"

namespace palp::fem::bench {
namespace {

/// Options of a threaded run at secondary rate @p f.
AsyncRegionsOptions threadedOptions(const Config& c, double f) {
    AsyncRegionsOptions o;
    o.primaryNodes = c.nodes.front();
    o.secondaryRate = f;
    applySecondaryOptions(c, o);
    o.threaded = !c.sync;
    o.globalSecondary = c.global;
    o.slideZoneMaxDofs = c.zoneMax;
    o.secondaryCpu = 1;
    return o;
}

/// What a threaded run measured.
struct ThreadedRun {
    std::vector<double> tickTimes, force, swapTicks;
    int overruns = 0, moves = 0, adopted = 0, maxDelay = 0;
    double wall = 0.0;
    double outsidePrimary = 0.0;  // slide: largest spring weight on non-primary nodes
};

/// The run's two lines: "threaded ..." and, with moves, "  moving contact: ...".
void report(const Config& c, const AsyncRegions& a, double f, const ThreadedRun& r,
            const Run& ref) {
    const AsyncSecondaryStats s = a.secondaryStats();
    std::printf(
        "threaded %d^3 lod %d %s%s N %d f %.0f Hz (%d substeps): tick mean %.4f ms, p99 %.4f "
        "ms, max %.4f ms, overruns %d; secondary %llu solves in %.2f s (%.1f Hz, wanted %.0f), "
        "last solve %.2f ms (CPU %.2f ms), max %.2f ms, %llu used; peak %.4f N vs reference "
        "%.4f N (%.2f%%), rms err %.2f%%\n",
        c.size, c.lod, c.solver == LinearSolverKind::cholmod ? "CHOLMOD" : "PCG",
        c.fullField ? " full field" : "", a.primaryFreeNodeCount(), f,
        static_cast<int>(std::lround(1e-3 / a.substepSeconds())), mean(r.tickTimes) * 1e3,
        percentile(r.tickTimes, 0.99) * 1e3, percentile(r.tickTimes, 1.0) * 1e3, r.overruns,
        static_cast<unsigned long long>(s.solves), r.wall, static_cast<double>(s.solves) / r.wall,
        f, s.lastSolveSeconds * 1e3, s.lastSolveCpuSeconds * 1e3, s.maxSolveSeconds * 1e3,
        static_cast<unsigned long long>(s.used), peak(r.force), peak(ref.force),
        100.0 * relErr(peak(r.force), peak(ref.force)), 100.0 * rmsErr(r.force, ref.force));
    if (c.moveMs <= 0) return;
    const bool slide = c.contact != "jump";
    char how[160];
    if (slide) {
        std::snprintf(how, sizeof how,
                      "sliding %.0f mm/s, filter %.1f mm, k %.0f N/m, lead %.0f ms, spring "
                      "weight outside the primary max %.1f%%; reference slides the same spring",
                      5e3 / c.moveMs, c.filterMm, c.stiffness, c.leadMs, 100.0 * r.outsidePrimary);
    } else {
        std::snprintf(how, sizeof how, "contact jumps a node; reference follows the moves");
    }
    std::printf(
        "  moving contact: %d requests, %d layouts adopted, last preparation %.1f ms "
        "(secondary thread), swap ticks max %.4f ms, force finite %s, max |F| %.4f N; "
        "adopted %.0f%%, request to adoption max %d ticks; %s\n",
        r.moves, r.adopted, s.lastPrepareSeconds * 1e3, percentile(r.swapTicks, 1.0) * 1e3,
        std::all_of(r.force.begin(), r.force.end(), [](double v) { return std::isfinite(v); })
            ? "yes"
            : "no",
        peak(r.force), 100.0 * r.adopted / std::max(1, r.moves), r.maxDelay, how);
}

/// Sleeps to the next 1 ms deadline of a wall-clock servo loop, or counts an overrun.
void keepPace(Clock::time_point& deadline, Clock::time_point tickEnd, int& overruns) {
    deadline += std::chrono::microseconds(1000);
    if (tickEnd > deadline) {
        ++overruns;
    } else {
        std::this_thread::sleep_until(deadline);
    }
}

/// The contact node of a moving-contact run at tick @p t (1-based): every moveMs ticks it moves
/// one node along +x across the top face (wrapping to x = 1), as threaded() requests it.
int movingContactAt(const Config& c, const Problem& p, int t) {
    if (c.moveMs <= 0) return p.contact;
    int x = c.size / 2;
    for (int k = c.moveMs; k <= t; k += c.moveMs) x = x + 1 < c.size - 1 ? x + 1 : 1;
    return p.model.mesh().node(x, c.size / 2, c.size - 1);
}

/// Whole-mesh reference that follows the moving contact with the switch semantics of
/// AsyncRegions, at the request tick: the old contact node is released with its displacement
/// and velocity, the new one moves from its displacement to the tick's target within the tick.
/// The central difference of ExplicitSolver (lumped mass, mass-proportional damping; the bench
/// material has no stiffness damping), whose constraints are fixed at construction.
Run movingReference(const Config& c, const Problem& p) {
    const FemModel& m = p.model;
    const int dofs = m.dofCount();
    const Eigen::VectorXd& mass = m.lumpedMass();
    const double critical = 0.9 * m.criticalTimeStep();
    const int substeps = std::max(1, static_cast<int>(std::ceil(1e-3 / critical)));
    const double dt = 1e-3 / substeps, alpha = m.material().dampingAlpha;
    std::vector<char> fixed(static_cast<std::size_t>(dofs), 0);
    for (int d = 0; d < dofs; ++d) fixed[static_cast<std::size_t>(d)] = p.constraints.isFixed(d);
    Eigen::VectorXd u = Eigen::VectorXd::Zero(dofs), up = u, f = u;
    Run r;
    const int ticks = static_cast<int>(std::lround(c.seconds / 1e-3));
    for (int t = 1; t <= ticks; ++t) {
        const int contact = movingContactAt(c, p, t);
        const Eigen::Vector3d start = u.segment<3>(3 * contact);
        const Eigen::Vector3d target(0, 0, inputAt(c, t * 1e-3, false));
        for (int s = 0; s < substeps; ++s) {
            f.setZero();
            m.addStiffnessTimes(u.data(), f.data());
            for (int d = 0; d < dofs; ++d) {
                if (fixed[static_cast<std::size_t>(d)] || mass[d] <= 0.0) continue;
                up[d] = (-dt * dt * f[d] + 2.0 * mass[d] * u[d] -
                         (1.0 - 0.5 * dt * alpha) * mass[d] * up[d]) /
                        ((1.0 + 0.5 * dt * alpha) * mass[d]);
            }
            up.segment<3>(3 * contact) = start + (s + 1.0) / substeps * (target - start);
            u.swap(up);
        }
        r.force.push_back(-f[3 * contact + 2]);
    }
    return r;
}

/// The sliding finger of --contact slide: where it is at any time, and the coupling spring that
/// presses the top face under it for one tick (identical for the regions and the reference but
/// for the tangential target, which is each solver's own filtered point: no tangential force).
class SlidingFinger {
  public:
    SlidingFinger(const Config& c, const Problem& p) : mC(c), mP(p) {
        const int span = 2 * static_cast<int>(std::ceil(3.0 * c.filterMm / 5.0)) + 2;
        mNodes.reserve(static_cast<std::size_t>(span * span));
        mWeights.reserve(mNodes.capacity());
    }

    /// x of the contact point in node units at @p t seconds: from size/2 along +x at one node
    /// per moveMs, reflected at 1 and size - 2.
    double x(double t) const {
        const double lo = 1.0, hi = mC.size - 2.0, span = hi - lo;
        const double d = std::fmod(mC.size / 2 - lo + t * 1e3 / mC.moveMs, 2.0 * span);
        return lo + (d <= span ? d : 2.0 * span - d);
    }

    /// The top node nearest the point at @p t seconds.
    int nearestNode(double t) const {
        return mP.model.mesh().node(static_cast<int>(std::lround(x(t))), mC.size / 2, mC.size - 1);
    }

    /// The spring of tick @p tick (1-based: from (tick - 1) ms to tick ms), the point taken at
    /// the tick's start; @p u gives a node's displacement now (its tangential target).
    template <class Displacement>
    const CouplingSpring& at(int tick, Displacement&& u) {
        const double t0 = (tick - 1) * 1e-3, t1 = tick * 1e-3;
        weigh(x(t0));
        mSpring.nodes = mNodes;
        mSpring.weights = mWeights;
        mSpring.stiffness = mC.stiffness;
        Eigen::Vector3d a = Eigen::Vector3d::Zero();
        for (std::size_t i = 0; i < mNodes.size(); ++i) {
            const Eigen::Vector3d un = u(mNodes[i]);
            if (un.allFinite()) a += mWeights[i] * un;
        }
        const double z0 = inputAt(mC, t0, false), z1 = inputAt(mC, t1, false);
        mSpring.target = Eigen::Vector3d(a.x(), a.y(), z0);
        mSpring.targetVelocity = Eigen::Vector3d(0, 0, (z1 - z0) / 1e-3);
        mSpring.damping = criticalDamping(mP.model, mSpring, mC.dampingRatio);
        return mSpring;
    }

    /// Sum of the current weights on nodes not in the sorted @p primary.
    double weightOutside(const std::vector<int>& primary) const {
        double w = 0.0;
        for (std::size_t i = 0; i < mNodes.size(); ++i)
            if (!std::binary_search(primary.begin(), primary.end(), mNodes[i])) w += mWeights[i];
        return w;
    }

  private:
    /// Normalised Gaussian weights (DeformableBody's filter, on the undeformed top face) of the
    /// nodes within 3 sigma of the point at node coordinate @p px; sigma 0: linear weights.
    void weigh(double px) {
        mNodes.clear();
        mWeights.clear();
        const HexMesh& mesh = mP.model.mesh();
        const int y0 = mC.size / 2, z = mC.size - 1;
        if (mC.filterMm <= 0.0) {
            const int i0 = std::min(static_cast<int>(std::floor(px)), mC.size - 2);
            const double f = px - i0;
            mNodes = {mesh.node(i0, y0, z), mesh.node(i0 + 1, y0, z)};
            mWeights = {1.0 - f, f};
            return;
        }
        const double h = 5.0, sigma = mC.filterMm, cutoff = 3.0 * sigma;  // mm
        const int reach = static_cast<int>(std::floor(cutoff / h)) + 1;
        double total = 0.0;
        for (int j = y0 - reach; j <= y0 + reach; ++j) {
            for (int i = static_cast<int>(std::floor(px)) - reach;
                 i <= static_cast<int>(std::ceil(px)) + reach; ++i) {
                if (i < 0 || j < 0 || i >= mC.size || j >= mC.size) continue;
                const double dx = (i - px) * h, dy = (j - y0) * h, d2 = dx * dx + dy * dy;
                if (d2 > cutoff * cutoff) continue;
                mNodes.push_back(mesh.node(i, j, z));
                mWeights.push_back(std::exp(-d2 / (2.0 * sigma * sigma)));
                total += mWeights.back();
            }
        }
        for (double& w : mWeights) w /= total;
    }

    const Config& mC;
    const Problem& mP;
    std::vector<int> mNodes;
    std::vector<double> mWeights;
    CouplingSpring mSpring;
};

/// The whole mesh under the sliding finger: ExplicitSolver::step(dt, spring) every tick.
Run slideReference(const Config& c, const Problem& p) {
    ExplicitSolver s(p.model, p.constraints);
    SlidingFinger finger(c, p);
    Run r;
    const int ticks = static_cast<int>(std::lround(c.seconds / 1e-3));
    for (int t = 1; t <= ticks; ++t) {
        const CouplingSpring& spring = finger.at(
            t, [&](int n) -> Eigen::Vector3d { return s.displacement().segment<3>(3 * n); });
        SpringResult out;
        s.step(1e-3, spring, &out);
        r.force.push_back(-out.meanForce.z());
    }
    return r;
}

/// The regions under the sliding finger (force drive), asked for the node nearest the point
/// leadMs ahead whenever that node changes.
ThreadedRun slideRun(const Config& c, const Problem& p, AsyncRegions& a) {
    SlidingFinger finger(c, p);
    ThreadedRun r;
    const int ticks = static_cast<int>(std::lround(c.seconds / 1e-3));
    int asked = finger.nearestNode(c.leadMs * 1e-3), requestTick = 0;
    if (asked != a.contactNodes().front()) {
        a.requestContactNode(asked);
        ++r.moves;
    }
    const auto start = Clock::now();
    auto deadline = start;
    for (int t = 1; t <= ticks; ++t) {
        const int want = finger.nearestNode((t - 1 + c.leadMs) * 1e-3);
        if (want != asked) {
            a.requestContactNode(want);
            asked = want;
            ++r.moves;
            requestTick = t;
        }
        const CouplingSpring& spring = finger.at(t, [&](int n) { return a.nodeDisplacement(n); });
        // Synchronous: a layout changes at the end of a tick, so this tick runs on the current
        // one; threaded: at the start of the tick that adopts it.
        if (c.sync)
            r.outsidePrimary = std::max(r.outsidePrimary, finger.weightOutside(a.primaryNodes()));
        const auto b = Clock::now();
        const AsyncTickResult res = a.tick(std::span<const NodalLoad>{}, spring);
        const auto e = Clock::now();
        if (!c.sync)
            r.outsidePrimary = std::max(r.outsidePrimary, finger.weightOutside(a.primaryNodes()));
        r.tickTimes.push_back(std::chrono::duration<double>(e - b).count());
        if (res.layoutChanged) {
            ++r.adopted;
            r.swapTicks.push_back(r.tickTimes.back());
            r.maxDelay = std::max(r.maxDelay, t - requestTick);
        }
        r.force.push_back(-res.spring.meanForce.z());
        keepPace(deadline, e, r.overruns);
    }
    r.wall = std::chrono::duration<double>(Clock::now() - start).count();
    return r;
}

/// A threaded run with a driven contact node: still, or (--contact jump) jumping one node along
/// +x every moveMs ticks.
ThreadedRun jumpRun(const Config& c, const Problem& p, AsyncRegions& a) {
    ThreadedRun r;
    const int ticks = static_cast<int>(std::lround(c.seconds / 1e-3));
    int requestTick = 0;
    const int y = c.size / 2, z = c.size - 1;
    int x = c.size / 2;
    const auto start = Clock::now();
    auto deadline = start;
    for (int t = 1; t <= ticks; ++t) {
        if (c.moveMs > 0 && t % c.moveMs == 0) {
            x = x + 1 < c.size - 1 ? x + 1 : 1;
            a.requestContactNode(p.model.mesh().node(x, y, z));
            ++r.moves;
            requestTick = t;
        }
        const auto b = Clock::now();
        const AsyncTickResult res = a.tick(Eigen::Vector3d(0, 0, inputAt(c, t * 1e-3, false)));
        const auto e = Clock::now();
        r.tickTimes.push_back(std::chrono::duration<double>(e - b).count());
        if (res.layoutChanged) {
            ++r.adopted;
            r.swapTicks.push_back(r.tickTimes.back());
            r.maxDelay = std::max(r.maxDelay, t - requestTick);
        }
        r.force.push_back(-res.contactForce.z());
        keepPace(deadline, e, r.overruns);
    }
    r.wall = std::chrono::duration<double>(Clock::now() - start).count();
    return r;
}

}  // namespace

void threaded(const Config& c) {
    const Problem p(c);
    const bool slide = c.moveMs > 0 && c.contact != "jump";
    const Run ref = slide          ? slideReference(c, p)
                    : c.moveMs > 0 ? movingReference(c, p)
                                   : reference(c, p, false);
    palp::pinCurrentThread(0);  // best effort, as before: a refused pin only changes timings
    for (double f : c.rates) {
        AsyncRegionsOptions o = threadedOptions(c, f);
        // A sliding finger without --n: the library's default primary (30 seeds), as a
        // DeformableBody built without the tool's options has.
        if (slide && !c.nodesGiven) o.primaryNodes = AsyncRegionsOptions{}.primaryNodes;
        if (slide) {
            o.drive = ContactDrive::force;
            // As DeformableBody: the surface under the finger is watched, so the spring's nodes
            // outside the primary enter a(u) with their secondary displacement (unwatched ones
            // would count as zero and stiffen the contact by about their weight).
            if (c.watch) o.watchNodes = p.model.mesh().faceNodes(BoxFace::zMax);
        }
        AsyncRegions a(p.model, p.constraints, {p.contact}, o);
        const ThreadedRun r = slide ? slideRun(c, p, a) : jumpRun(c, p, a);
        report(c, a, f, r, ref);
    }
}

}  // namespace palp::fem::bench
