// Deformable palpation on asynchronous regions (DeformableSolver::asyncRegions): a stiff press on
// fine regions at equilibrium, quasi-static press against the implicit solve and the whole-mesh
// explicit body, a session, bone, a sliding contact that moves the region centre, zero
// allocations, bad options.
#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <iostream>
#include <limits>
#include <new>
#include <random>
#include <string>
#include <thread>
#include <vector>

#include "alloc_counter.h"
#include "alloc_failure.h"
#include "deformable_fixtures.h"
#include "palp/base/error.h"
#include "palp/fem/async_regions.h"
#include "palp/fem/implicit_solver.h"
#include "palp/haptics/session.h"
#include "palp/haptics/tissue/deformable.h"
#include "palp/haptics/tissue/deformable_setup.h"
#include "palp/kernels/embree_scene.h"
#include "palp/volume/phantom.h"
#include "session_fixtures.h"

namespace palp::haptics {
namespace {

using namespace dfix;

// The test cube on asynchronous regions (@p seeds primary seeds) centred under the origin of
// the top face; synchronous (deterministic) unless @p threaded.
std::shared_ptr<DeformableModel> asyncCube(double filterWidth, bool threaded = false,
                                           int seeds = 30) {
    DeformableOptions o;
    o.filterWidth = filterWidth;
    o.solverKind = DeformableSolver::asyncRegions;
    o.regions.threaded = threaded;
    o.regions.primaryNodes = seeds;
    o.regions.secondaryRate = 100;
    o.regionsCentre = Eigen::Vector3d::Zero();
    return DeformableModel::box(Eigen::Vector3d::Constant(0.04), {9, 9, 9}, softTissue(),
                                fem::BoxFace::yMax, o, mm(-20, 0, -20));
}

// The quasi-static secondary has no inertia: with 30 seeds the coupling must stay below about
// twice the contact's static stiffness (deformable.h, "Stability with regions").
constexpr double kAsyncK = 50;

// (6) A held press with a stiff coupling (k 800 N/m) on fine regions tissue (2.5 mm cells,
// as on a ~33^3-node body; palp palpate's 60 seeds at 100 Hz) settles at the quasi-static
// equilibrium with a steady force. With the condensed correction of Gamma applied at every
// primary substep this press chattered: ripple 46 % here, and on the bone phantom's
// 35,301-node body the force swung to 2.2 N (0.17 N static); once per tick (the default of
// DeformableOptions) it holds (bench/README.md).
TEST(DeformableAsync, FineRegionsPressHoldsAtEquilibrium) {
    DeformableOptions o;
    o.solverKind = DeformableSolver::asyncRegions;
    o.regions.threaded = false;
    o.regions.primaryNodes = 60;
    o.regions.secondaryRate = 100;
    o.regions.lod = 2;
    o.regionsCentre = Eigen::Vector3d::Zero();
    auto model = DeformableModel::box(Eigen::Vector3d::Constant(0.02), {9, 9, 9}, softTissue(),
                                      fem::BoxFace::yMax, o, mm(-10, 0, -10));
    auto scene = deformableScene(model);
    PathDevice device({{0.0, mm(0, -3, 0)}, {0.5, mm(0, 3, 0)}, {1.5, mm(0, 3, 0)}});
    Session session(scene, device, vcParams(800));
    std::vector<double> hold;
    Snapshot s;
    double observerMin = 0;
    for (int i = 0; i < 1500; ++i) {
        s = session.step();
        ASSERT_TRUE(s.force.allFinite());
        ASSERT_EQ(s.femFlags, 0u) << "tick " << i;
        observerMin = std::min(observerMin, s.observerEnergy);
        if (i >= 1250) {
            EXPECT_GT(s.contactCount, 0) << "tick " << i;
            hold.push_back(s.force.norm());
        }
    }
    double mean = 0, var = 0;
    for (const double f : hold) mean += f / static_cast<double>(hold.size());
    for (const double f : hold) var += (f - mean) * (f - mean) / static_cast<double>(hold.size());
    EXPECT_GT(mean, 0.02);
    EXPECT_LE(std::sqrt(var) / mean, 0.05) << "mean |F| " << mean;
    EXPECT_GE(observerMin, 0.0);
    const DeformableBody* body = session.deformable();
    const Eigen::VectorXd ref = quasiStatic(*model, contactLoad(*body, s.tissueForce));
    const int node = s.contactNode;
    ASSERT_GE(node, 0);
    const double uy = body->displacement()[3 * node + 1], uyRef = ref[3 * node + 1];
    EXPECT_NEAR(uy, uyRef, 0.05 * uyRef);
    EXPECT_NEAR(s.proxy.y(), uy, 0.1e-3);
}

// (6) A constant force held on the regions body settles where the implicit quasi-static solve
// of the same nodal load puts it, and where the whole-mesh explicit body does, over the whole
// free surface, with a primary region that is a small part of the mesh.
TEST(DeformableAsync, ConstantForceSettlesOnQuasiStaticAndExplicitBody) {
    const Eigen::Vector3d force(0.05, 0.3, -0.02);
    auto model = asyncCube(3e-3);
    DeformableBody body(model);
    ASSERT_NE(body.regions(), nullptr);
    const int node = body.applyContactForce(Eigen::Vector3d::Zero(), force);
    EXPECT_EQ(node, topCentreNode(*model));
    EXPECT_EQ(body.requestedCentre(), node);
    EXPECT_EQ(body.recentreRequests(), 0);
    EXPECT_LT(body.regions()->primaryFreeNodeCount(), model->model().mesh().nodeCount() / 4);
    for (int i = 0; i < 1500; ++i) ASSERT_EQ(body.step(kT), 0u) << "tick " << i;
    const Eigen::VectorXd ref = quasiStatic(*model, body.nodalForce());
    auto explicitModel = cube(3e-3);
    DeformableBody whole(explicitModel);
    whole.applyContactForce(Eigen::Vector3d::Zero(), force);
    for (int i = 0; i < 1500; ++i) whole.step(kT);
    const Eigen::Vector3d u = body.displacement().segment<3>(3 * node);
    const Eigen::Vector3d uRef = ref.segment<3>(3 * node);
    EXPECT_GT(uRef.y(), 1e-4);
    EXPECT_NEAR(u.y(), uRef.y(), 0.01 * uRef.y());
    EXPECT_LT((u - whole.displacement().segment<3>(3 * node)).norm(), 0.02 * uRef.norm());
    double worst = 0;
    for (int n : model->loadNodes())
        worst = std::max(worst, (body.displacement() - ref).segment<3>(3 * n).norm());
    EXPECT_LT(worst, 0.02 * uRef.norm());
    EXPECT_NEAR(body.maxSurfaceDisplacement(), whole.maxSurfaceDisplacement(), 0.02 * uRef.norm());
    // The deformed surface is what the proxy traces: the anchored point follows the contact.
    ASSERT_TRUE(body.anchor(body.nodePosition(node) - mm(0, 0.5, 0), Eigen::Vector3d(0, -1, 0)));
    EXPECT_NEAR(body.anchoredPosition().y(), u.y() - 0.5e-3, 1e-6);
}

// Runs @p session over @p ticks, checking finiteness, FEM flags and Newton's third law (the
// tissue's force of a tick, the coupling spring's mean over it, leads the hand's by at most
// the spring's change as the probe and the surface move, as in the whole-mesh test).
Snapshot runAsyncSession(Session& session, int ticks, int* contactTicks = nullptr) {
    static thread_local Snapshot prev;
    Snapshot s;
    const double k = session.params().coupling.baseStiffness;
    for (int i = 0; i < ticks; ++i) {
        s = session.step();
        EXPECT_TRUE(s.force.allFinite()) << "tick " << i;
        EXPECT_EQ(s.femFlags, 0u) << "tick " << i;
        if (s.contactCount > 0) {
            if (contactTicks) ++*contactTicks;
            if (prev.contactCount > 0 && s.tick == prev.tick + 1) {
                const double moved = (s.probe - prev.probe).norm() + (s.proxy - prev.proxy).norm();
                // The condensed correction of Gamma is applied once per tick (at its first
                // substep), so the tissue's mean force over the tick lags its border's motion
                // within the tick: up to 2e-4 of the force besides the spring's change.
                EXPECT_LE((prev.tissueForce + prev.force).norm(),
                          2 * k * moved + 1e-5 + 2e-4 * prev.tissueForce.norm())
                    << "tick " << s.tick;
            }
        }
        prev = s;
        if (!s.force.allFinite() || s.femFlags != 0) break;
    }
    return s;
}

// (6) Through a session (synchronous regions): the steady press is the quasi-static one under
// the final nodal load, Newton's third law holds at every tick, the proxy sits on the surface;
// k = 100 N/m is steady once the primary carries enough mass (100 seeds).
TEST(DeformableAsync, SessionSteadyPressMatchesQuasiStatic) {
    for (const auto& [k, seeds] : {std::pair{kAsyncK, 30}, std::pair{100.0, 100}}) {
        auto model = asyncCube(3e-3, false, seeds);
        auto scene = deformableScene(model);
        PathDevice device({{0.0, mm(0, -5, 0)}, {0.6, mm(0, 4, 0)}, {1.6, mm(0, 4, 0)}});
        Session session(scene, device, vcParams(k));
        int contactTicks = 0;
        const Snapshot s = runAsyncSession(session, 1600, &contactTicks);
        EXPECT_GT(contactTicks, 900);
        ASSERT_GT(s.contactCount, 0);
        const DeformableBody* body = session.deformable();
        ASSERT_NE(body->regions(), nullptr);
        EXPECT_GT(-s.force.y(), 0.05);
        const Eigen::VectorXd ref = quasiStatic(*model, contactLoad(*body, s.tissueForce));
        const int node = s.contactNode;
        ASSERT_GE(node, 0);
        const double uy = body->displacement()[3 * node + 1], uyRef = ref[3 * node + 1];
        EXPECT_GT(uyRef, 1e-3);
        EXPECT_NEAR(uy, uyRef, 0.03 * uyRef) << "k " << k;
        EXPECT_NEAR(s.proxy.y(), uy, 0.1e-3);
        EXPECT_EQ(body->regions()->contactNodes()[0], node);  // centred under the contact
    }
}

// (6) Bone nodes are fixed in the regions too (exactly zero in the whole field) while the
// tissue above them moves.
TEST(DeformableAsync, BoneNodesStayFixed) {
    volume::PhantomSpec spec;
    spec.params.scene = volume::PhantomScene::Bone;
    spec.voxelSize = 2e-3;
    const volume::Volume vol = volume::makePhantomVolume(spec);
    fem::VoxelizeOptions vo;
    vo.elementSize = 5e-3;
    vo.boneThreshold = 500;
    DeformableOptions o;
    o.solverKind = DeformableSolver::asyncRegions;
    o.regions.threaded = false;
    o.regions.secondaryRate = 100;
    o.regionsCentre = Eigen::Vector3d::Zero();
    const auto model = DeformableModel::fromVolume(vol, vo, softTissue(), fem::BoxFace::yMax, o);
    DeformableBody body(model);
    body.applyContactForce(mm(0, 0, 0), Eigen::Vector3d(0, 1.0, 0));
    for (int i = 0; i < 300; ++i) ASSERT_EQ(body.step(kT), 0u) << "tick " << i;
    EXPECT_GT(body.maxSurfaceDisplacement(), 1e-3);
    const Eigen::VectorXd u = body.regions()->displacement();  // whole field (not real-time)
    double aboveBone = 0;
    int bone = 0;
    for (int n = 0; n < model->model().mesh().nodeCount(); ++n) {
        const Eigen::Vector3d x = model->model().mesh().nodePosition(n);
        if (std::abs(x.x()) < 3e-3 && std::abs(x.z()) < 3e-3 && std::abs(x.y() - 0.02) < 1e-4)
            aboveBone = std::max(aboveBone, u.segment<3>(3 * n).norm());
        if (!model->constraints().isFixed(3 * n) || x.y() < 0.02 || x.y() > 0.036) continue;
        ++bone;
        EXPECT_EQ(u.segment<3>(3 * n), Eigen::Vector3d::Zero()) << "node " << n;
        EXPECT_EQ(body.regions()->nodeDisplacement(n), Eigen::Vector3d::Zero()) << "node " << n;
    }
    EXPECT_GT(bone, 100);
    EXPECT_GT(aboveBone, 1e-6);
}

// (6) A press that slides 16 mm across the top (session, synchronous regions): the region
// centre follows the contact (several layouts) and the surface stays within the whole-mesh
// explicit body's range on the same hand path (a layout change hands entering nodes the
// secondary's static values, at rest: a transient, not a jump); after the hold the
// indentation is the quasi-static one under the final load.
TEST(DeformableAsync, CentreFollowsASlidingContact) {
    const std::vector<PathDevice::Key> path{
        {0.0, mm(-8, -3, 0.3)}, {0.4, mm(-8, 4, 0.3)}, {1.2, mm(8, 4, 0.3)}, {1.6, mm(8, 4, 0.3)}};
    auto runPath = [&](std::shared_ptr<DeformableModel> model, double& largest) {
        auto scene = deformableScene(model);
        PathDevice device(path);
        auto session = std::make_unique<Session>(scene, device, vcParams(kAsyncK));
        largest = 0;
        Snapshot s;
        for (int i = 0; i < 1600; ++i) {
            s = runAsyncSession(*session, 1);
            if (!s.force.allFinite() || s.femFlags != 0) break;
            largest = std::max(largest, session->deformable()->maxSurfaceDisplacement());
        }
        return std::make_pair(std::move(session), s);
    };
    auto model = asyncCube(3e-3, false, 60);
    double largest = 0, largestWhole = 0;
    const auto [session, s] = runPath(model, largest);
    runPath(cube(3e-3), largestWhole);
    const DeformableBody* body = session->deformable();
    ASSERT_GT(s.contactCount, 0);
    EXPECT_GE(body->recentreRequests(), 2);
    EXPECT_EQ(body->regions()->contactNodes()[0], s.contactNode);
    EXPECT_GT(body->nodePosition(s.contactNode).x(), 4e-3);
    std::printf(
        "sliding press: largest surface displacement %.3f mm (whole-mesh body %.3f mm), "
        "%d centre moves\n",
        largest * 1e3, largestWhole * 1e3, body->recentreRequests());
    EXPECT_LT(largest, 1.5 * largestWhole);
    const Eigen::VectorXd ref = quasiStatic(*model, contactLoad(*body, s.tissueForce));
    const double uy = body->displacement()[3 * s.contactNode + 1];
    EXPECT_NEAR(uy, ref[3 * s.contactNode + 1], 0.03 * ref[3 * s.contactNode + 1]);
}

// (6) Zero allocations per tick: the body on synchronous regions between secondary solves,
// and a session on threaded regions (the secondary thread stalled while counting: its solver
// allocates).
TEST(DeformableAsync, TicksAllocateNothing) {
    {
        auto model = asyncCube(3e-3);
        DeformableBody body(model);
        int counted = 0;
        for (int i = 0; i < 300; ++i) {
            const Eigen::Vector3d p = mm(-3 + 0.02 * i, 0, 0.3);
            const std::uint64_t before = test::allocationCount();
            body.applyContactForce(p, Eigen::Vector3d(0, 0.2, 0));
            body.anchor(p - mm(0, 0.1, 0), Eigen::Vector3d(0, -1, 0));
            body.step(kT);
            const std::uint64_t n = test::allocationCount() - before;
            if ((i + 1) % body.regions()->periodTicks() != 0) {
                EXPECT_EQ(n, 0u) << "tick " << i;
                ++counted;
            }
        }
        EXPECT_GT(counted, 250);
    }
    auto model = asyncCube(3e-3, /*threaded=*/true);
    auto scene = deformableScene(model);
    PathDevice device({{0.0, mm(0, -5, 0)},
                       {0.3, mm(0, 6, 0)},
                       {0.6, mm(6, 4, -5)},
                       {0.7, mm(6, -5, -5)},
                       {1.0, mm(-5, 5, 5)}});
    Session session(scene, device, vcParams(kAsyncK));
    fem::AsyncRegions* regions = const_cast<DeformableBody*>(session.deformable())->regions();
    ASSERT_NE(regions, nullptr);
    for (int i = 0; i < 100; ++i) {
        session.step();
        std::this_thread::sleep_for(std::chrono::microseconds(300));
    }
    EXPECT_GT(regions->secondaryStats().used, 0u);
    regions->setSecondaryStalledForTest(true);
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
    // The ticks' own thread (the servo's work): a layout build already running on the
    // secondary's builder thread when the stall began allocates, and may.
    const std::uint64_t before = test::threadAllocationCount();
    int contact = 0, stale = 0;
    for (int i = 100; i < 1000; ++i) {
        const Snapshot& s = session.step();
        contact += s.contactCount > 0 ? 1 : 0;
        // The stalled secondary is flagged to the host once 0.5 s of ticks pass without a
        // solution (fem::kAsyncSecondaryStale); nothing else.
        stale += (s.femFlags & fem::kAsyncSecondaryStale) ? 1 : 0;
        if (!s.force.allFinite() || (s.femFlags & ~fem::kAsyncSecondaryStale) != 0) {
            ADD_FAILURE() << "tick " << i << " flags " << s.femFlags;
            break;
        }
    }
    EXPECT_EQ(test::threadAllocationCount() - before, 0u);
    EXPECT_GT(contact, 300);
    EXPECT_GT(stale, 0);
    regions->setSecondaryStalledForTest(false);
}

// Allocation failure at set-up on threaded regions (issue 38 item 4): the per-session body
// starts the secondary's threads while it is built, so a failure on the host's thread after
// they started must stop and join them on the way out (a joinable std::thread destroyed would
// end the process). For 12 k (3 under TSan) across a whole construction: std::bad_alloc, no thread
// left running; then a Session builds and presses.
TEST(DeformableAsync, AnAllocationFailureAtSetUpStopsTheRegionsThreads) {
    auto model = asyncCube(3e-3, /*threaded=*/true);
    auto scene = deformableScene(model);
    PathDevice device({{0.0, mm(0, -5, 0)}, {0.3, mm(0, 2, 0)}, {1.0, mm(0, 2, 0)}});
    const std::uint64_t before = test::threadAllocationCount();
    std::uint64_t total = 0;
    {
        Session probe(scene, device, vcParams(kAsyncK));
        total = test::threadAllocationCount() - before;  // the construction's own
    }
    ASSERT_GT(total, 10u);
#if defined(__SANITIZE_THREAD__)
    constexpr std::uint64_t kPoints = 3;  // a construction takes ~18 s under TSan
#else
    constexpr std::uint64_t kPoints = 12;
#endif
    const int thrown = test::buildUnderEachAllocationFailure(
        total, kPoints, [&] { Session s(scene, device, vcParams(kAsyncK)); });
    EXPECT_GT(thrown, 0);
    Session session(scene, device, vcParams(kAsyncK));
    Snapshot s;
    for (int i = 0; i < 600; ++i) {
        s = session.step();
        std::this_thread::sleep_for(std::chrono::microseconds(100));
    }
    EXPECT_TRUE(s.force.allFinite());
    EXPECT_GT(s.contactCount, 0);
}

// (6) The regions' lod follows the zone a sliding contact needs. On the bone phantom's body at
// 2.5 mm cells (40 x 20 x 40 cells, pressed on y = 0, palp palpate's 60 seeds) the zone at lod 2
// is 5,292 dofs, over the cap of 3,000: every move of the contact was assembled and factorised
// (seconds), so a live raster ran out of its primary (contact in 47-60 % of the ticks) and an
// offline one took minutes. lod 4 keeps it at 1,089; the 5 mm body keeps lod 2.
TEST(DeformableAsync, AutoLodKeepsTheSlideZoneWithinItsCap) {
    const auto body = [](double cellMm, int cells) {
        DeformableOptions o;
        o.solverKind = DeformableSolver::asyncRegions;
        o.regions.threaded = false;
        o.regions.primaryNodes = 60;
        o.regions.lod = 1;
        o.regionsCentre = Eigen::Vector3d::Zero();
        const double side = cellMm * cells;
        return DeformableModel::box(mm(side, side / 2, side), {cells + 1, cells / 2 + 1, cells + 1},
                                    softTissue(), fem::BoxFace::yMax, o,
                                    mm(-side / 2, 0, -side / 2));
    };
    const auto zone = [](const DeformableModel& m, int lod) {
        fem::AsyncRegionsOptions o = m.options().regions;
        o.lod = lod;
        return fem::AsyncRegions::slideZoneDofs(m.model(), m.constraints(), {m.regionsCentreNode()},
                                                o);
    };
    const auto fine = body(2.5, 40);
    const int cap = fine->options().regions.slideZoneMaxDofs;
    EXPECT_EQ(zone(*fine, 2), 5292);
    EXPECT_GT(zone(*fine, 2), cap);
    EXPECT_EQ(zone(*fine, 4), 1089);
    EXPECT_EQ(autoRegionsLod(fine->model().mesh()), 2);  // the lattice alone
    EXPECT_EQ(autoRegionsLod(*fine), 4);
    const auto coarse = body(5.0, 20);
    EXPECT_LE(zone(*coarse, 2), cap);
    EXPECT_EQ(autoRegionsLod(*coarse), 2);
}

TEST(DeformableAsync, RejectsBadOptionsAndTimeStep) {
    DeformableOptions o;
    o.recentreHysteresis = 1.0;
    EXPECT_THROW(validateDeformableOptions(o), ValueError);
    auto model = asyncCube(3e-3);
    DeformableBody body(model);
    EXPECT_EQ(body.step(2 * kT), static_cast<unsigned>(fem::kStepBadTimeStep));
    EXPECT_EQ(body.regions()->time(), 0.0);
    EXPECT_TRUE(body.requestRegionsCentre(mm(10, 0, 10)));
    EXPECT_EQ(body.recentreRequests(), 1);
    EXPECT_FALSE(body.requestRegionsCentre(Eigen::Vector3d::Constant(std::nan(""))));
    DeformableBody plain(cube(3e-3));
    EXPECT_EQ(plain.regions(), nullptr);
    EXPECT_FALSE(plain.requestRegionsCentre(Eigen::Vector3d::Zero()));
    // A session whose servo period is not the regions' tick would freeze the tissue: refused.
    auto scene = deformableScene(model);
    PathDevice device({{0.0, mm(0, -5, 0)}});
    SessionParams p = vcParams(kAsyncK);
    p.servo.periodSeconds = 2 * kT;
    try {
        Session bad(scene, device, p);
        ADD_FAILURE() << "a 2 ms servo period with a 1 ms regions tick was accepted";
    } catch (const ValueError& e) {
        EXPECT_NE(std::string(e.what()).find("regions.tickSeconds"), std::string::npos) << e.what();
    }
}
}  // namespace
}  // namespace palp::haptics
