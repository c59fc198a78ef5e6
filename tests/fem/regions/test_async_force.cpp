// Asynchronous FEM regions driven by nodal forces (ContactDrive::force) and the watched-node
// displacements: the quasi-static limit against ImplicitSolver (loads on primary and on
// secondary nodes, lod 1 and 2, the period average of intermittent secondary loads), a
// sinusoidal force against the whole-mesh ExplicitSolver, watched values across a contact
// change, zero allocations per tick, a stalled secondary, bad input.
#include <gtest/gtest.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <numbers>
#include <random>
#include <thread>

#include "alloc_counter.h"
#include "palp/base/error.h"
#include "palp/fem/async_regions.h"
#include "palp/fem/explicit_solver.h"
#include "palp/fem/implicit_solver.h"

namespace palp::fem {
namespace {

constexpr double kTick = 1e-3;

/// Cube of n^3 nodes, h = 5 mm, soft tissue (E 5 kPa, nu 0.45) with mass-proportional damping,
/// bottom fixed; the contact (region centre) at the centre of the top face.
struct Problem {
    int n;
    FemModel model;
    Constraints constraints;
    int contact;
    Problem(int nodes, double alpha)
        : n(nodes),
          model(HexMesh::box(Eigen::Vector3d::Constant(0.005 * (nodes - 1)), {nodes, nodes, nodes},
                             5e3),
                ElasticMaterial{5e3, 0.45, 1e3, alpha, 0.0}),
          constraints(model.dofCount()),
          contact(model.mesh().node(nodes / 2, nodes / 2, nodes - 1)) {
        constraints.fixNodes(model.mesh().faceNodes(BoxFace::zMin));
    }
    int top(int i, int j) const { return model.mesh().node(i, j, n - 1); }
};

/// Quasi-static whole-mesh solution under constant nodal loads.
Eigen::VectorXd staticSolution(const Problem& p, const std::vector<NodalLoad>& loads) {
    ImplicitSolver s(p.model, p.constraints, {Integrator::quasiStatic, LinearSolverKind::cholmod});
    s.externalForce().setZero();
    for (const NodalLoad& l : loads) s.externalForce().segment<3>(3 * l.node) += l.force;
    s.step(1.0);
    return s.displacement();
}

AsyncRegionsOptions forceOptions() {
    AsyncRegionsOptions o;
    o.drive = ContactDrive::force;
    o.primaryNodes = 30;
    o.secondaryRate = 100.0;
    o.secondaryIntegrator = Integrator::quasiStatic;
    return o;
}

/// Ramps @p loads in over @p ramp ticks and holds them until tick @p ticks.
void runStatic(AsyncRegions& a, const std::vector<NodalLoad>& loads, int ticks, int ramp = 200) {
    std::vector<NodalLoad> now = loads;
    for (int t = 1; t <= ticks; ++t) {
        const double s = std::min(1.0, t / static_cast<double>(ramp));
        for (std::size_t i = 0; i < loads.size(); ++i) now[i].force = s * loads[i].force;
        const AsyncTickResult r = a.tick(now);
        ASSERT_EQ(r.flags, 0u) << "tick " << t;
        ASSERT_TRUE(r.contactDisplacement.allFinite());
    }
}

double relDiff(const Eigen::Vector3d& a, const Eigen::Vector3d& b) {
    return (a - b).norm() / b.norm();
}

/// A static press on the top of the 13^3 cube (the contact node and its four neighbours, as a
/// filtered coupling force would load them) settles to the whole mesh's quasi-static solution:
/// at the loaded node, at a far surface node (secondary, watched) and over the whole field.
TEST(AsyncForce, StaticPressMatchesImplicitQuasiStaticSolve) {
    const Problem p(13, 150.0);
    const int c = 6;
    std::vector<NodalLoad> loads{{p.contact, {0, 0, -0.04}},
                                 {p.top(c - 1, c), {0, 0, -0.01}},
                                 {p.top(c + 1, c), {0, 0, -0.01}},
                                 {p.top(c, c - 1), {0.004, 0, -0.01}},
                                 {p.top(c, c + 1), {0, 0, -0.01}}};
    const Eigen::VectorXd ref = staticSolution(p, loads);
    const int far = p.top(2, 10);
    AsyncRegionsOptions o = forceOptions();
    o.watchNodes = {far, p.top(1, 1), p.top(11, 6), p.contact};
    AsyncRegions a(p.model, p.constraints, {p.contact}, o);
    const auto& prim = a.primaryNodes();
    ASSERT_TRUE(std::binary_search(prim.begin(), prim.end(), p.contact));
    ASSERT_FALSE(std::binary_search(prim.begin(), prim.end(), far));
    runStatic(a, loads, 700);
    const Eigen::Vector3d uContact = a.nodeDisplacement(p.contact);
    const Eigen::Vector3d uFar = a.nodeDisplacement(far);
    const Eigen::Vector3d refContact = ref.segment<3>(3 * p.contact);
    const Eigen::Vector3d refFar = ref.segment<3>(3 * far);
    std::printf("static press: contact %.4f mm (reference %.4f mm), far node %.5f mm (%.5f mm)\n",
                -uContact.z() * 1e3, -refContact.z() * 1e3, -uFar.z() * 1e3, -refFar.z() * 1e3);
    EXPECT_LT(relDiff(uContact, refContact), 0.01);
    EXPECT_LT(relDiff(uFar, refFar), 0.02);
    EXPECT_LT(refFar.norm(), 0.2 * refContact.norm());  // far: a real test of the secondary
    EXPECT_GT(refFar.norm(), 1e-3 * refContact.norm());
    const Eigen::VectorXd u = a.displacement();
    EXPECT_LT((u - ref).norm(), 0.01 * ref.norm());
    // The watched values are the field's values.
    std::vector<Eigen::Vector3d> w(o.watchNodes.size() + 2);
    ASSERT_EQ(a.watchedDisplacements(w), o.watchNodes.size());
    for (std::size_t i = 0; i < o.watchNodes.size(); ++i)
        EXPECT_LT((w[i] - u.segment<3>(3 * o.watchNodes[i])).norm(), 1e-3 * refContact.norm());
    // Fixed nodes read their (zero) constraint; unwatched secondary nodes are unknown.
    EXPECT_EQ(a.nodeDisplacement(p.model.mesh().node(3, 3, 0)), Eigen::Vector3d::Zero());
    EXPECT_TRUE(a.nodeDisplacement(p.top(0, 12)).hasNaN());
    EXPECT_TRUE(a.nodeDisplacement(-1).hasNaN());
}

/// Loads on secondary nodes only (a corner of the top face, far from the primary region) reach
/// the secondary's right-hand side: the body moves as the whole-mesh reference does (lod 1), and
/// with lod 2 (restricted with I^T) the coarse secondary is a little stiffer but takes the same
/// load.
TEST(AsyncForce, LoadOnSecondaryNodesIsNotLost) {
    const Problem p(13, 150.0);
    const int corner = p.top(2, 2);
    const std::vector<NodalLoad> loads{{corner, {0.01, 0, -0.03}}, {p.top(3, 2), {0, 0, -0.02}}};
    const Eigen::VectorXd ref = staticSolution(p, loads);
    const Eigen::Vector3d refCorner = ref.segment<3>(3 * corner);
    const Eigen::Vector3d refContact = ref.segment<3>(3 * p.contact);
    for (int lod : {1, 2}) {
        AsyncRegionsOptions o = forceOptions();
        o.lod = lod;
        o.watchNodes = {corner};
        AsyncRegions a(p.model, p.constraints, {p.contact}, o);
        const auto& prim = a.primaryNodes();
        const auto& gamma = a.secondaryBorderNodes();
        ASSERT_FALSE(std::binary_search(prim.begin(), prim.end(), corner));
        ASSERT_EQ(std::find(gamma.begin(), gamma.end(), corner), gamma.end());
        runStatic(a, loads, 700);
        const Eigen::Vector3d uCorner = a.nodeDisplacement(corner);
        const Eigen::Vector3d uContact = a.nodeDisplacement(p.contact);
        std::printf(
            "lod %d, secondary load: corner %.4f mm (reference %.4f), contact %.5f mm "
            "(%.5f)\n",
            lod, -uCorner.z() * 1e3, -refCorner.z() * 1e3, -uContact.z() * 1e3,
            -refContact.z() * 1e3);
        if (lod == 1) {
            EXPECT_LT(relDiff(uCorner, refCorner), 0.005);
            EXPECT_LT(relDiff(uContact, refContact), 0.01);  // carried back into the primary
        } else {
            // Coarse: a subspace, so less compliant at the load, by less than a third here.
            EXPECT_LT(uCorner.norm(), refCorner.norm());
            EXPECT_GT(uCorner.norm(), 0.66 * refCorner.norm());
            EXPECT_GT(uCorner.dot(refCorner), 0.95 * uCorner.norm() * refCorner.norm());
        }
    }
}

/// A load on a secondary node present only on some ticks of each secondary period acts with its
/// period average (its impulse), whatever ticks it falls on: nothing between solves is lost.
TEST(AsyncForce, IntermittentSecondaryLoadActsWithItsPeriodAverage) {
    const Problem p(13, 150.0);
    const int corner = p.top(2, 2);
    const NodalLoad full{corner, {0, 0, -0.05}};
    const Eigen::VectorXd ref = staticSolution(p, {full});
    AsyncRegionsOptions o = forceOptions();
    o.watchNodes = {corner};
    AsyncRegions a(p.model, p.constraints, {p.contact}, o);
    ASSERT_EQ(a.periodTicks(), 10);
    for (int t = 1; t <= 700; ++t) {
        // 3 ticks in 10, at the end of the period (just before the secondary solve) and at its
        // start: 30 % of the load on average.
        const int phase = t % 10;
        const bool on = phase == 0 || phase == 9 || phase == 1;
        const NodalLoad l = on ? full : NodalLoad{corner, Eigen::Vector3d::Zero()};
        ASSERT_EQ(a.tick(std::span<const NodalLoad>(&l, 1)).flags, 0u);
    }
    const Eigen::Vector3d u = a.nodeDisplacement(corner);
    const Eigen::Vector3d expect = 0.3 * ref.segment<3>(3 * corner);
    EXPECT_LT(relDiff(u, expect), 0.005);
}

/// A raised-cosine force at the contact against the whole mesh stepped explicitly every tick on
/// the same input. The quasi-static secondary ignores the far field's inertia: the displacement
/// error grows with the input frequency (reported; bounded here).
TEST(AsyncForce, SinusoidalForceFollowsWholeMeshExplicit) {
    const Problem p(13, 10.0);
    const int ticks = 600;
    const double amplitude = 0.05;
    for (double frequency : {1.5, 6.0}) {
        auto forceAt = [&](int t) {
            return -amplitude * 0.5 *
                   (1.0 - std::cos(2.0 * std::numbers::pi * frequency * t * kTick));
        };
        ExplicitSolver whole(p.model, p.constraints);
        std::vector<double> ref;
        for (int t = 1; t <= ticks; ++t) {
            whole.externalForce()[3 * p.contact + 2] = forceAt(t);
            whole.step(kTick);
            ref.push_back(whole.displacement()[3 * p.contact + 2]);
        }
        double refPeak = 0.0;
        for (double v : ref) refPeak = std::max(refPeak, std::abs(v));
        for (const auto& [seeds, rate] : {std::pair{5, 50.0}, std::pair{30, 100.0}}) {
            AsyncRegionsOptions o = forceOptions();
            o.primaryNodes = seeds;
            o.secondaryRate = rate;
            AsyncRegions a(p.model, p.constraints, {p.contact}, o);
            double peak = 0.0, worst = 0.0;
            for (int t = 1; t <= ticks; ++t) {
                const NodalLoad l{p.contact, {0, 0, forceAt(t)}};
                const double z = a.tick(std::span<const NodalLoad>(&l, 1)).contactDisplacement.z();
                peak = std::max(peak, std::abs(z));
                worst = std::max(worst, std::abs(z - ref[static_cast<std::size_t>(t - 1)]));
            }
            const double peakErr = std::abs(peak - refPeak) / refPeak;
            std::printf(
                "sinusoidal force %.1f Hz, N %d f %.0f Hz: peak %.4f mm vs whole mesh %.4f mm "
                "(%.2f %%), largest error %.2f %% of the peak\n",
                frequency, seeds, rate, peak * 1e3, refPeak * 1e3, 100.0 * peakErr,
                100.0 * worst / refPeak);
            // Slow input: the far field's inertia is negligible; faster: it shows.
            EXPECT_LT(peakErr, frequency < 2.0 ? 0.01 : 0.04);
            EXPECT_LT(worst, (frequency < 2.0 ? 0.01 : 0.06) * refPeak);
            if (frequency > 2.0) {
                EXPECT_GT(worst, 0.005 * refPeak);
            }
        }
    }
}

/// Watched surface values stay continuous across a contact change in the force drive (the
/// nodes leaving the primary keep the values the servo showed until the secondary answers).
TEST(AsyncForce, WatchedValuesContinuousAcrossContactChange) {
    const Problem p(9, 150.0);
    std::vector<int> watch;
    for (int i = 0; i < 9; ++i)
        for (int j = 0; j < 9; ++j) watch.push_back(p.top(i, j));
    for (bool threaded : {false, true}) {
        AsyncRegionsOptions o = forceOptions();
        o.watchNodes = watch;
        o.threaded = threaded;
        AsyncRegions a(p.model, p.constraints, {p.contact}, o);
        std::vector<NodalLoad> loads{{p.top(4, 4), {0, 0, -0.03}}, {p.top(5, 4), {0, 0, -0.03}}};
        std::vector<Eigen::Vector3d> w(watch.size()), before(watch.size());
        int t = 0;
        for (; t < 400; ++t) {
            a.tick(loads);
            if (threaded) std::this_thread::sleep_for(std::chrono::microseconds(200));
        }
        double peak = 0.0;
        a.watchedDisplacements(before);
        for (const auto& v : before) peak = std::max(peak, v.norm());
        ASSERT_TRUE(a.requestContactNode(p.top(6, 4)));
        double worstStep = 0.0;
        bool changed = false;
        // Threaded: the layout is built on a low-priority thread (~0.1-1 s on a loaded machine)
        // while the servo keeps ticking.
        for (int k = 0, after = 0; k < 8000 && after < 300; ++k, ++t) {
            const AsyncTickResult r = a.tick(loads);
            changed = changed || r.layoutChanged;
            if (changed) ++after;
            a.watchedDisplacements(w);
            for (std::size_t i = 0; i < w.size(); ++i) {
                ASSERT_TRUE(w[i].allFinite()) << "node " << watch[i];
                worstStep = std::max(worstStep, (w[i] - before[i]).norm());
            }
            std::swap(w, before);
            if (threaded) std::this_thread::sleep_for(std::chrono::microseconds(200));
        }
        EXPECT_TRUE(changed) << (threaded ? "threaded" : "synchronous");
        EXPECT_EQ(a.contactNodes()[0], p.top(6, 4));
        EXPECT_LT(worstStep, 0.02 * peak) << (threaded ? "threaded" : "synchronous");
    }
}

/// A sweep's step that passes over the unchanged (watchedChanges, the deformable body's swept
/// surface): for every watched node (the top face, and bottom-face nodes with fixed dofs) and
/// shown values exactly current, within and beyond the tolerance, a period old or near the value
/// a period ended with (one end of the interpolation, the other micrometres off), each node
/// written out carries nodeDisplacement()'s value bit for bit, each node passed over is within
/// the tolerance of what is shown, P, Gamma and fixed nodes are never passed over, and a
/// sweep in small pieces finds the same nodes as one in a piece.
TEST(AsyncForce, WatchedChangesPassOverOnlyWhatCannotHaveMoved) {
    const Problem p(9, 150.0);
    std::vector<int> watch;
    for (int i = 0; i < 9; ++i)
        for (int j = 0; j < 9; ++j) watch.push_back(p.top(i, j));
    for (int i = 0; i < 9; i += 2) watch.push_back(p.model.mesh().node(i, 4, 0));  // fixed
    AsyncRegionsOptions o = forceOptions();
    o.watchNodes = watch;
    AsyncRegions a(p.model, p.constraints, {p.contact}, o);
    const std::size_t n = watch.size();
    constexpr double kStill = 1e-6;
    std::vector<Eigen::Vector3d> old(n), ended(n), now(n), out(n);
    std::vector<std::uint32_t> index(n);
    std::vector<double> shown(3 * n);
    std::mt19937 rng(7);
    std::uniform_int_distribution<int> pick(0, 4);
    int checked = 0, passedOver = 0;
    for (int t = 1; t <= 400; ++t) {
        // A press that changes until tick 250 (the surface moves every period), then held
        // (the solutions repeat: the unchanged can be passed over), then creeping from tick 320
        // (solutions a few micrometres apart: ends on both sides of the tolerance).
        const double s = std::min(1.0, t / 150.0) * (1.0 + 0.15 * std::max(0, t - 320) / 80.0);
        const double flick = t < 250 ? static_cast<double>(t % 37 < 20) : 0.0;
        a.tick(std::vector<NodalLoad>{{p.top(4, 4), {0.01 * s, 0, -0.03 * s}},
                                      {p.top(5, 4), {0, 0, -0.02 * s * flick}}});
        if (t % 10 == 7) a.watchedDisplacements(old);
        if (t % 10 == 0) a.watchedDisplacements(ended);  // a period's end: one of its ends
        if (t < 160 || t % 13 != 3) continue;            // mid-period ticks, after the ramp
        ASSERT_EQ(a.watchedDisplacements(now), n);
        for (std::size_t i = 0; i < n; ++i) {
            Eigen::Vector3d v = now[i];
            switch (pick(rng)) {
                case 0:
                    break;  // as shown now
                case 1:
                    v += Eigen::Vector3d(0.4, -0.4, 0.2) * kStill;
                    break;  // within
                case 2:
                    v.y() += 3 * kStill;
                    break;  // beyond
                case 3:
                    v = old[i];
                    break;  // a period old
                default:
                    v = ended[i] + Eigen::Vector3d::Constant(0.5 * kStill);
                    break;  // near an end of the interpolation, the other maybe not
            }
            for (int k = 0; k < 3; ++k) shown[3 * i + static_cast<std::size_t>(k)] = v[k];
        }
        const WatchedChanges c = a.watchedChanges(0, n, shown, kStill, index, out);
        ASSERT_EQ(c.examined, n);
        std::vector<bool> written(n, false);
        for (std::size_t k = 0; k < c.changed; ++k) {
            ASSERT_LT(index[k], n);
            written[index[k]] = true;
            EXPECT_EQ(out[k], now[index[k]]) << "watched node " << index[k];
        }
        const auto& prim = a.primaryNodes();
        const auto& gamma = a.secondaryBorderNodes();
        double max2 = 0;
        for (std::size_t i = 0; i < n; ++i) {
            const Eigen::Vector3d v(shown[3 * i], shown[3 * i + 1], shown[3 * i + 2]);
            const bool own = std::find(prim.begin(), prim.end(), watch[i]) != prim.end() ||
                             std::find(gamma.begin(), gamma.end(), watch[i]) != gamma.end();
            if (own || i >= 81) {
                EXPECT_TRUE(written[i]) << "P, Gamma or fixed: node " << watch[i];
            }
            if (written[i]) continue;
            ++passedOver;
            EXPECT_LT((now[i] - v).cwiseAbs().maxCoeff(), kStill) << "node " << watch[i];
            max2 = std::max(max2, v.squaredNorm());
        }
        EXPECT_EQ(c.skippedMax2, max2);
        // The same sweep in pieces of at most 3 written nodes, resumed where each stopped.
        std::vector<std::uint32_t> pieces;
        for (std::size_t first = 0; first < n;) {
            const WatchedChanges q =
                a.watchedChanges(first, n - first, shown, kStill, std::span(index).first(3),
                                 std::span(out).first(3));
            ASSERT_GT(q.examined, 0u);
            for (std::size_t k = 0; k < q.changed; ++k) pieces.push_back(index[k]);
            first += q.examined;
        }
        std::vector<std::uint32_t> whole;
        for (std::size_t i = 0; i < n; ++i)
            if (written[i]) whole.push_back(static_cast<std::uint32_t>(i));
        EXPECT_EQ(pieces, whole);
        ++checked;
    }
    EXPECT_GE(checked, 15);
    EXPECT_GT(passedOver, 50);  // it does pass over the unchanged (once the press is held)
}

/// The same with a load that keeps growing through the contact change (synchronous, so the
/// swap falls on a secondary period boundary): watched nodes that the servo does not integrate
/// restart their interpolation from the value shown at the swap, so the surface keeps moving
/// along the ramp: no step backwards of more than 3 steady steps (a restart from the previous
/// solution falls back by a whole period's growth: 9 steady steps at 100 Hz, measured).
TEST(AsyncForce, WatchedValuesFollowAGrowingLoadAcrossContactChange) {
    const Problem p(9, 150.0);
    std::vector<int> watch;
    for (int i = 0; i < 9; ++i)
        for (int j = 0; j < 9; ++j) watch.push_back(p.top(i, j));
    AsyncRegionsOptions o = forceOptions();
    o.watchNodes = watch;
    AsyncRegions a(p.model, p.constraints, {p.contact}, o);
    std::vector<Eigen::Vector3d> w(watch.size()), before(watch.size());
    auto loadsAt = [&](int t) {
        const double f = -0.03 * std::min(1.0, t / 1500.0);
        return std::vector<NodalLoad>{{p.top(4, 4), {0, 0, f}}, {p.top(5, 4), {0, 0, f}}};
    };
    // Per watched node: its largest per-tick step on the steady ramp, and around the change.
    std::vector<double> steady(watch.size(), 0.0), around(watch.size(), 0.0);
    std::vector<Eigen::Vector3d> at300(watch.size()), dir(watch.size());
    std::vector<int> shownBefore;
    bool changed = false;
    for (int t = 0; t < 1000; ++t) {
        if (t == 600) {
            shownBefore = a.primaryNodes();
            const auto& g = a.secondaryBorderNodes();
            shownBefore.insert(shownBefore.end(), g.begin(), g.end());
            ASSERT_TRUE(a.requestContactNode(p.top(6, 4)));
        }
        const AsyncTickResult r = a.tick(loadsAt(t));
        changed = changed || r.layoutChanged;
        a.watchedDisplacements(w);
        for (std::size_t i = 0; i < w.size(); ++i) {
            if (t == 300) at300[i] = w[i];
            if (t == 599) dir[i] = (w[i] - at300[i]).normalized();
            const double step = (w[i] - before[i]).norm();
            if (t >= 300 && t < 600) steady[i] = std::max(steady[i], step);
            // Around the change: the largest step backwards along the node's steady motion.
            if (t >= 600) around[i] = std::max(around[i], -(w[i] - before[i]).dot(dir[i]));
        }
        std::swap(w, before);
    }
    ASSERT_TRUE(changed);
    // The nodes shown from the secondary's interpolation in both layouts (the servo integrates
    // P and Gamma, whose entering nodes ring for a while after the swap: that is the primary's
    // transient, tested above and in MovingLoadWithContactChangesFollowsWholeMesh).
    std::vector<std::uint8_t> servoShown(static_cast<std::size_t>(p.model.mesh().nodeCount()), 0);
    auto mark = [&](const std::vector<int>& nodes) {
        for (int n : nodes) servoShown[static_cast<std::size_t>(n)] = 1;
    };
    mark(shownBefore);
    mark(a.primaryNodes());
    mark(a.secondaryBorderNodes());
    double worst = 0.0;
    std::size_t worstNode = 0, checked = 0;
    for (std::size_t i = 0; i < watch.size(); ++i) {
        if (servoShown[static_cast<std::size_t>(watch[i])]) continue;
        ++checked;
        ASSERT_GT(steady[i], 0.0) << "node " << watch[i];
        if (around[i] / steady[i] > worst) {
            worst = around[i] / steady[i];
            worstNode = i;
        }
    }
    EXPECT_GT(checked, 20u);
    EXPECT_LT(worst, 3.0) << "node " << watch[worstNode] << ": steady " << steady[worstNode]
                          << " m per tick, around the change " << around[worstNode];
}

/// A load pattern (normal and tangential) that steps one node along x every 150 ticks, with the
/// region centre requested along: against the whole mesh (primary = every node) on the same
/// loads. A layout change hands the entering nodes the secondary's static values at rest, and a
/// load that steps onto secondary nodes acts one to two periods late: transients of up to a
/// fifth of the displacement (reported), settled within 1 % of the whole mesh by the end of
/// each dwell.
TEST(AsyncForce, MovingLoadWithContactChangesFollowsWholeMesh) {
    const Problem p(9, 60.0);
    std::vector<int> watch;
    for (int i = 0; i < 9; ++i)
        for (int j = 0; j < 9; ++j) watch.push_back(p.top(i, j));
    constexpr int kDwell = 150, kTicks = 750;
    auto run = [&](int seeds, std::vector<int>& changes) {
        AsyncRegionsOptions o = forceOptions();
        o.watchNodes = watch;
        o.primaryNodes = seeds;
        AsyncRegions a(p.model, p.constraints, {p.top(2, 4)}, o);
        std::vector<Eigen::Vector3d> w(watch.size());
        std::vector<double> top;  // largest top-face displacement per tick
        for (int t = 0; t < kTicks; ++t) {
            const int x = 2 + t / kDwell;
            if (t % kDwell == 0 && t > 0) {
                EXPECT_TRUE(a.requestContactNode(p.top(x, 4)));
            }
            const std::vector<NodalLoad> loads{{p.top(x, 4), {0.02, 0, -0.03}},
                                               {p.top(x + 1, 4), {0.01, 0, -0.02}}};
            const AsyncTickResult r = a.tick(loads);
            EXPECT_EQ(r.flags, 0u);
            if (r.layoutChanged) changes.push_back(t);
            a.watchedDisplacements(w);
            double m = 0;
            for (const auto& v : w) m = std::max(m, v.norm());
            top.push_back(m);
        }
        EXPECT_EQ(a.contactNodes()[0], p.top(2 + (kTicks - 1) / kDwell, 4));
        return top;
    };
    std::vector<int> changes, wholeChanges;
    const std::vector<double> got = run(30, changes);
    const std::vector<double> ref = run(p.model.mesh().nodeCount(), wholeChanges);
    ASSERT_EQ(changes.size(), 4u);
    for (std::size_t k = 0; k < changes.size(); ++k)  // at the period boundary after the request
        EXPECT_EQ(changes[k], kDwell * static_cast<int>(k + 1) + 9);
    double worst = 0, peak = 0;
    for (std::size_t t = 0; t < got.size(); ++t) {
        ASSERT_TRUE(std::isfinite(got[t]));
        worst = std::max(worst, std::abs(got[t] - ref[t]));
        peak = std::max(peak, ref[t]);
    }
    std::printf("moving load: largest deviation from the whole mesh %.1f %% of its peak\n",
                100.0 * worst / peak);
    EXPECT_LT(worst, 0.3 * peak);
    for (int t = kDwell - 1; t < kTicks; t += kDwell) {
        const std::size_t i = static_cast<std::size_t>(t);
        EXPECT_NEAR(got[i], ref[i], 0.01 * ref[i]) << "end of dwell, tick " << t;
    }
}

TEST(AsyncForce, TicksAllocateNothing) {
    const Problem p(9, 10.0);
    std::vector<int> watch;
    for (int i = 0; i < 9; ++i)
        for (int j = 0; j < 9; ++j) watch.push_back(p.top(i, j));
    const std::vector<NodalLoad> loads{{p.contact, {0, 0, -0.02}},
                                       {p.top(4, 3), {0, 0, -0.01}},
                                       {p.top(1, 1), {0, 0, -0.01}}};  // secondary
    std::vector<Eigen::Vector3d> w(watch.size());
    // Synchronous: every tick but the period boundaries (which solve the secondary inline).
    {
        AsyncRegionsOptions o = forceOptions();
        o.watchNodes = watch;
        AsyncRegions a(p.model, p.constraints, {p.contact}, o);
        int counted = 0;
        for (int t = 1; t <= 300; ++t) {
            const std::uint64_t before = palp::test::allocationCount();
            a.tick(loads);
            a.watchedDisplacements(w);
            const std::uint64_t n = palp::test::allocationCount() - before;
            if (t % a.periodTicks() != 0) {
                EXPECT_EQ(n, 0u) << "tick " << t;
                ++counted;
            }
        }
        EXPECT_GT(counted, 200);
    }
    // Threaded: every tick (the secondary thread allocates in its solver: stalled meanwhile).
    {
        AsyncRegionsOptions o = forceOptions();
        o.watchNodes = watch;
        o.threaded = true;
        o.secondaryRate = 500.0;
        AsyncRegions a(p.model, p.constraints, {p.contact}, o);
        for (int t = 1; t <= 50; ++t) {
            a.tick(loads);
            std::this_thread::sleep_for(std::chrono::microseconds(200));
        }
        EXPECT_GT(a.secondaryStats().used, 0u);
        a.setSecondaryStalledForTest(true);
        std::this_thread::sleep_for(std::chrono::milliseconds(20));
        const std::uint64_t before = palp::test::allocationCount();
        for (int t = 0; t < 300; ++t) {
            a.tick(loads);
            a.watchedDisplacements(w);
        }
        EXPECT_EQ(palp::test::allocationCount() - before, 0u);
        a.setSecondaryStalledForTest(false);
    }
}

/// Threaded, with the secondary stalled on purpose while the load keeps pressing: the primary
/// keeps running against a frozen far field (stiffer, so it moves less), finite and bounded.
TEST(AsyncForce, StalledSecondaryStaysFiniteAndBounded) {
    const Problem p(9, 10.0);
    const std::vector<NodalLoad> loads{{p.contact, {0, 0, -0.03}}, {p.top(1, 1), {0, 0, -0.01}}};
    const Eigen::VectorXd ref = staticSolution(p, loads);
    const double refContact = ref.segment<3>(3 * p.contact).norm();
    AsyncRegionsOptions o = forceOptions();
    o.threaded = true;
    o.secondaryRate = 200.0;
    o.watchNodes = {p.top(1, 1)};
    AsyncRegions a(p.model, p.constraints, {p.contact}, o);
    int sinceSolution = 0;  // ticks since the last one a solution entered at
    const auto tick = [&] {
        const AsyncTickResult r = a.tick(loads);
        sinceSolution = r.secondaryUpdated ? 0 : sinceSolution + 1;
        return r;
    };
    for (int t = 1; t <= 100; ++t) {
        tick();
        std::this_thread::sleep_for(std::chrono::microseconds(200));
    }
    a.setSecondaryStalledForTest(true);
    // A solve already under way when the stall is set still finishes and publishes (a whole-
    // field solve with loads is two solves: tens of milliseconds under ThreadSanitizer or a
    // loaded machine). Wait until the count of finished solves has been still for 100 ms (at
    // most 20 s), then let the primary take up what was published.
    auto solves = a.secondaryStats().solves;
    for (int quiet = 0, i = 0; quiet < 100 && i < 20000; ++i) {
        std::this_thread::sleep_for(std::chrono::milliseconds(1));
        const auto now = a.secondaryStats().solves;
        quiet = now == solves ? quiet + 1 : 0;
        solves = now;
    }
    tick();
    tick();
    const auto usedAtStall = a.secondaryStats().used;
    const int sinceAtStall = sinceSolution;
    double worst = 0.0;
    int flagged = 0, firstFlagged = -1;
    for (int t = 0; t < 1500; ++t) {
        const AsyncTickResult r = tick();
        ASSERT_TRUE(r.contactDisplacement.allFinite());
        EXPECT_FALSE(r.secondaryUpdated);
        worst = std::max(worst, r.contactDisplacement.norm());
        ASSERT_TRUE(a.nodeDisplacement(p.top(1, 1)).allFinite());
        if (r.flags & kAsyncSecondaryStale) {
            ++flagged;
            if (firstFlagged < 0) firstFlagged = t;
        }
    }
    EXPECT_EQ(a.secondaryStats().used, usedAtStall);
    EXPECT_LT(worst, 3.0 * refContact);
    // Flagged stale on the first tick more than 0.5 s of ticks (500) after the last solution,
    // and on every tick from then on.
    EXPECT_EQ(firstFlagged, 500 - sinceAtStall);
    EXPECT_EQ(flagged, 1500 - firstFlagged);
    a.setSecondaryStalledForTest(false);
    bool resumed = false;
    for (int t = 0; t < 2000 && !resumed; ++t) {
        const AsyncTickResult r = a.tick(loads);
        resumed = r.secondaryUpdated;
        if (resumed) {
            EXPECT_EQ(r.flags & kAsyncSecondaryStale, 0u);  // cleared by the solution
        }
        std::this_thread::sleep_for(std::chrono::microseconds(200));
    }
    EXPECT_TRUE(resumed);
}

TEST(AsyncForce, RejectsBadInputAndRefusesBadLoads) {
    const Problem p(9, 10.0);
    AsyncRegionsOptions o = forceOptions();
    o.maxLoads = 0;
    EXPECT_THROW(AsyncRegions(p.model, p.constraints, {p.contact}, o), ValueError);
    o.maxLoads = 2;
    o.watchNodes = {p.contact, p.contact};
    EXPECT_THROW(AsyncRegions(p.model, p.constraints, {p.contact}, o), ValueError);
    o.watchNodes = {p.model.mesh().nodeCount()};
    EXPECT_THROW(AsyncRegions(p.model, p.constraints, {p.contact}, o), ValueError);
    o.watchNodes = {};
    AsyncRegions a(p.model, p.constraints, {p.contact}, o);
    // The displacement overload is not this drive's: nothing happens.
    EXPECT_NE(a.tick(Eigen::Vector3d(0, 0, -1e-3)).flags & kStepBadForce, 0u);
    EXPECT_EQ(a.time(), 0.0);
    const std::vector<NodalLoad> loads{{p.contact, {0, 0, -0.01}},
                                       {-4, {0, 0, -0.01}},
                                       {p.contact, {0, std::nan(""), 0}},
                                       {p.top(4, 3), {0, 0, -0.01}},
                                       {p.top(3, 4), {0, 0, -0.01}}};  // beyond maxLoads
    const AsyncTickResult r = a.tick(loads);
    EXPECT_NE(r.flags & kAsyncLoadsRefused, 0u);
    EXPECT_EQ(r.loadsRefused, 3);
    EXPECT_NEAR(r.contactForce.z(), -0.02, 1e-15);  // the two taken
    EXPECT_TRUE(r.contactDisplacement.allFinite());
    // A displacement-driven object refuses the load overload.
    AsyncRegions d(p.model, p.constraints, {p.contact}, AsyncRegionsOptions{});
    EXPECT_NE(d.tick(loads).flags & kStepBadForce, 0u);
    EXPECT_EQ(d.time(), 0.0);
}

}  // namespace
}  // namespace palp::fem
