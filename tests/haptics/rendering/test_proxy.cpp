// The god-object proxy with Coulomb friction (docs/algorithms.md section 1): stick and slip on a
// plane, a closed box from outside and as a room (edges and corners), free space and bad input,
// no allocation in contact, parameter checks. Curved and faceted surfaces (a sphere's
// iso-surface, concave folds, a noisy scan's skin) are in test_proxy_surfaces.cpp.
#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <iomanip>
#include <iostream>
#include <limits>
#include <random>
#include <string>
#include <vector>

#include "alloc_counter.h"
#include "palp/base/error.h"
#include "palp/haptics/rendering/proxy.h"
#include "proxy_fixtures.h"
#include "ray_test_shapes.h"

namespace {

using namespace palp::haptics::pfix;  // Vector3d, Proxy*, kernels' mesh types, kK, kDt, meshes

// ---- 1. Plane: stick, slip, tangential force, no friction ----

// Pressed D below the proxy's plane and dragged sideways: the proxy does not move while
// s / D <= mu_s; the first step past it leaves a lateral lag of exactly mu_d D; then the
// stick-slip saw-tooth repeats between mu_d D and mu_s D.
TEST(Proxy, PlaneStickThenSlipToDynamicCone) {
    PlaneScene ps;
    ProxyParams params;
    params.staticFriction = 0.5;
    params.dynamicFriction = 0.3;
    Proxy proxy(ps.scene, params);
    proxy.reset({0, 0, 1e-3});
    const double depth = 1e-3;                  // below the surface
    const double sep = depth + params.epsilon;  // D: proxy height minus probe height
    Vector3d probe(0, 0, -depth);
    const ProxyState& s0 = proxy.update(probe, kNoForce, kK, kDt);
    ASSERT_EQ(s0.contactCount, 1);
    EXPECT_TRUE(s0.sticking);
    EXPECT_NEAR(s0.position.z(), params.epsilon, 1e-15);
    EXPECT_NEAR(s0.normals[0].z(), 1.0, 1e-15);
    const Vector3d stuck = s0.position;

    const double step = 1e-6;
    int slips = 0;
    Vector3d last = stuck;
    for (int i = 1; i <= 1500; ++i) {
        probe.x() = i * step;
        const ProxyState& s = proxy.update(probe, kNoForce, kK, kDt);
        ASSERT_EQ(s.contactCount, 1);
        const double lag = probe.x() - last.x();  // lateral offset before this tick
        if (lag <= params.staticFriction * sep) {
            EXPECT_TRUE(s.sticking) << "tick " << i;
            EXPECT_EQ(s.position, last) << "tick " << i;  // exactly where it was
        } else {
            ++slips;
            EXPECT_FALSE(s.sticking);
            EXPECT_NEAR(probe.x() - s.position.x(), params.dynamicFriction * sep, 1e-9);
            EXPECT_NEAR(s.position.z(), params.epsilon, 1e-12);
            EXPECT_NEAR(s.velocity.x(), (s.position.x() - last.x()) / kDt, 1e-9);
            if (slips == 1) {
                // The first slip comes on the first tick with s / D > mu_s.
                EXPECT_GT(probe.x() / sep, params.staticFriction);
                EXPECT_LE((probe.x() - step) / sep, params.staticFriction);
                EXPECT_EQ(last, stuck);
            }
        }
        last = s.position;
    }
    // 1.5 mm of drag, 1 mm deep: first slip at 0.5 mm, then every (mu_s - mu_d) D = 0.2 mm.
    EXPECT_GE(slips, 5);
}

// A tangential force (AVCEC's F_py) on a stuck proxy tips |f_t| over mu_s f_n: it slides by
// (|f_t| - mu_d f_n) / k along f_t.
TEST(Proxy, TangentialForceMakesAStuckProxySlip) {
    PlaneScene ps;
    ProxyParams params;
    Proxy proxy(ps.scene, params);
    proxy.reset({0, 0, 1e-3});
    const double depth = 2e-3, sep = depth + params.epsilon;
    const Vector3d probe(0.4 * sep, 0, -depth);  // s / D = 0.4 < mu_s = 0.5
    proxy.update({0, 0, -depth}, kNoForce, kK, kDt);
    const ProxyState& s1 = proxy.update(probe, kNoForce, kK, kDt);
    ASSERT_TRUE(s1.sticking);
    const Vector3d stuck = s1.position;
    // A force against the pull keeps it stuck.
    const ProxyState& s2 = proxy.update(probe, Vector3d(-0.2, 0, 0), kK, kDt);
    EXPECT_TRUE(s2.sticking);
    EXPECT_EQ(s2.position, stuck);
    // Along +y: |f_t| = |(k 0.4 D, F)|; F = 0.3 k D gives |f_t| = 0.5 k D: still stuck (on
    // the cone); 0.35 k D tips it. Its normal part (-z) is ignored.
    const double fn = kK * sep;
    const ProxyState& s3 = proxy.update(probe, Vector3d(0, 0.3 * fn * (1 - 1e-9), 0), kK, kDt);
    EXPECT_TRUE(s3.sticking);
    EXPECT_EQ(s3.position, stuck);
    const Vector3d ft(kK * 0.4 * sep, 0.35 * fn, 0);
    const ProxyState& s4 = proxy.update(probe, Vector3d(0, 0.35 * fn, -5.0), kK, kDt);
    EXPECT_FALSE(s4.sticking);
    const Vector3d expected =
        stuck + (ft.norm() - params.dynamicFriction * fn) / kK * ft.normalized();
    EXPECT_NEAR((s4.position - expected).norm(), 0.0, 1e-12);
    EXPECT_NEAR(s4.position.z(), params.epsilon, 1e-15);
}

// Without friction the proxy is the probe projected onto the plane, epsilon above it, and
// follows the probe out when it leaves the surface.
TEST(Proxy, FrictionlessProxyIsTheProjectedProbe) {
    PlaneScene ps;
    ProxyParams params;
    params.staticFriction = params.dynamicFriction = 0;
    Proxy proxy(ps.scene, params);
    proxy.reset({0.01, 0.02, 5e-3});
    std::mt19937 rng(3);
    std::uniform_real_distribution<double> lateral(-0.05, 0.05), depth(-4e-3, -1e-6);
    for (int i = 0; i < 200; ++i) {
        const Vector3d probe(lateral(rng), lateral(rng), depth(rng));
        const ProxyState& s = proxy.update(probe, kNoForce, kK, kDt);
        ASSERT_EQ(s.contactCount, 1) << i;
        EXPECT_NEAR((s.position - Vector3d(probe.x(), probe.y(), params.epsilon)).norm(), 0, 1e-12)
            << i;
        EXPECT_NEAR(std::abs(s.tangent1.dot(s.normals[0])), 0, 1e-12);
        EXPECT_NEAR(s.tangent1.cross(s.tangent2).dot(s.normals[0]), 1, 1e-12);
    }
    const Vector3d out(0.01, 0, 2e-3);
    const ProxyState& s = proxy.update(out, kNoForce, kK, kDt);
    EXPECT_EQ(s.contactCount, 0);
    EXPECT_EQ(s.position, out);
    // The probe between the surface and the offset plane touches it (f_n > 0, tiny).
    proxy.update({0, 0, 2e-3}, kNoForce, kK, kDt);
    const ProxyState& t = proxy.update({0, 0, 0.5 * params.epsilon}, kNoForce, kK, kDt);
    EXPECT_EQ(t.contactCount, 1);
    EXPECT_NEAR(t.position.z(), params.epsilon, 1e-15);
}

// ---- 2. Closed box: never inside, bounded work, edges and corners ----

struct Counts {
    long ticks = 0, contact[4] = {0, 0, 0, 0};
    double worst = -std::numeric_limits<double>::infinity();  // max signed violation
};

/// Drives @p proxy along @p probe and checks after each tick: the proxy's violation
/// (penetration for the exterior, escape for the room) is <= 1e-9 m, queries are bounded,
/// the state is sane.
template <class Violation>
void tick(Proxy& proxy, const Vector3d& probe, Violation violation, Counts& c, double mu) {
    const Vector3d before = proxy.state().position;
    const ProxyState& s = proxy.update(probe, kNoForce, kK, kDt);
    ++c.ticks;
    ASSERT_TRUE(s.position.allFinite());
    ASSERT_GE(s.contactCount, 0);
    ASSERT_LE(s.contactCount, 3);
    ASSERT_LE(s.queries, 2 * (proxy.params().maxIterations + 1));
    ++c.contact[s.contactCount];
    const double v = violation(s.position);
    c.worst = std::max(c.worst, v);
    ASSERT_LE(v, 1e-9) << std::setprecision(17) << "tick " << c.ticks << " mu " << mu << " proxy "
                       << before.transpose() << " -> " << s.position.transpose() << " probe "
                       << probe.transpose() << " queries " << s.queries;
    for (int i = 0; i < s.contactCount; ++i)
        ASSERT_NEAR(s.normals[static_cast<std::size_t>(i)].norm(), 1, 1e-12);
}

/// Random probe paths around @p box: random walks (steps up to 2 mm), paths aimed through
/// edges and corners, and straight paths through the box and out the other side. The probe
/// starts on the proxy's side (outside for the exterior, inside for the room).
template <class Violation>
Counts runBoxPaths(const palp::test::Box& box, bool room, int ticks, Violation violation) {
    EmbreeScene scene;
    scene.addRigidMesh(boxMesh(box), kMaskSurface);
    scene.commit();
    Counts c;
    std::mt19937 rng(room ? 11 : 7);
    std::uniform_real_distribution<double> uni(-1, 1), unit(0, 1);
    const auto ball = [&](double r) -> Vector3d {
        Vector3d v;
        do v = Vector3d(uni(rng), uni(rng), uni(rng));
        while (v.squaredNorm() > 1);
        return r * v;
    };
    const double reach = room ? 6e-3 : 15e-3;  // how far outside the box the probe roams
    const auto startPoint = [&]() -> Vector3d {
        Vector3d p;
        do p = box.centre + (box.half + Vector3d::Constant(reach)).cwiseProduct(ball(1));
        while (room ? box.sdf(p) > -1e-3 : box.sdf(p) < 1e-3);
        return p;
    };
    const int pathTicks = 400;
    for (int path = 0; c.ticks < ticks; ++path) {
        ProxyParams params;
        const bool frictionless = path % 2 == 0;
        if (frictionless) params.staticFriction = params.dynamicFriction = 0;
        Proxy proxy(scene, params);
        const double mu = params.staticFriction;
        Vector3d probe = startPoint();
        proxy.reset(probe);
        const int kind = path % 3;
        if (kind == 0) {  // random walk
            for (int i = 0; i < pathTicks; ++i) {
                probe += ball(2e-3);
                const Vector3d rel = probe - box.centre;
                for (int a = 0; a < 3; ++a)  // reflect at the roaming box
                    if (std::abs(rel[a]) > box.half[a] + reach)
                        probe[a] -= 2 * (rel[a] > 0 ? 1 : -1) * 1e-3;
                tick(proxy, probe, violation, c, mu);
                if (::testing::Test::HasFatalFailure()) return c;
            }
        } else if (kind == 1) {  // at an edge or a corner, through it, then wiggling there
            Vector3d sign(uni(rng) > 0 ? 1 : -1, uni(rng) > 0 ? 1 : -1, uni(rng) > 0 ? 1 : -1);
            Vector3d q = box.centre + box.half.cwiseProduct(sign);
            if (unit(rng) < 0.6) {  // an edge: one coordinate free
                const int a = static_cast<int>(unit(rng) * 3) % 3;
                q[a] = box.centre[a] + box.half[a] * uni(rng);
                sign[a] = 0;
            }
            Vector3d out = sign + 0.3 * ball(1);  // outward across the edge or corner
            out.normalize();
            const Vector3d from =
                room ? Vector3d(box.centre + 0.5 * (q - box.centre)) : Vector3d(q + 8e-3 * out);
            const Vector3d to = q + (room ? 1.0 : -1.0) * unit(rng) * 4e-3 * out;
            probe = from;
            proxy.reset(probe);
            const int n = 20;
            for (int i = 1; i <= n; ++i) {
                probe = from + (to - from) * (double(i) / n);
                tick(proxy, probe, violation, c, mu);
                if (::testing::Test::HasFatalFailure()) return c;
            }
            for (int i = 0; i < pathTicks - n; ++i) {
                probe = to + ball(2.5e-3);
                tick(proxy, probe, violation, c, mu);
                if (::testing::Test::HasFatalFailure()) return c;
            }
        } else {  // straight through the box and out the other side, and back
            const Vector3d dir = ball(1).normalized();
            const Vector3d a = box.centre + 30e-3 * dir + ball(4e-3);
            const Vector3d b = box.centre - 30e-3 * dir + ball(4e-3);
            const Vector3d from = room ? box.centre + ball(2e-3) : a;
            probe = from;
            proxy.reset(probe);
            for (int i = 1; i <= pathTicks; ++i) {
                const double t = double(i % 60) / 30.0;  // there and back in 2 mm steps
                probe =
                    t <= 1 ? Vector3d(from + t * (b - from)) : Vector3d(b + (t - 1) * (from - b));
                tick(proxy, probe, violation, c, mu);
                if (::testing::Test::HasFatalFailure()) return c;
            }
        }
    }
    return c;
}

const palp::test::Box kBox{Vector3d(1.3e-3, -2.1e-3, 0.7e-3), Vector3d(10e-3, 8e-3, 6e-3)};

// From outside (a convex solid): never inside, and (almost) never more than one plane.
TEST(Proxy, BoxFromOutsideNeverInside) {
    const Counts c =
        runBoxPaths(kBox, false, 50000, [](const Vector3d& x) { return -kBox.sdf(x); });
    std::cout << "exterior: ticks " << c.ticks << ", planes 0/1/2/3: " << c.contact[0] << "/"
              << c.contact[1] << "/" << c.contact[2] << "/" << c.contact[3] << ", deepest proxy "
              << c.worst << " m\n";
    EXPECT_GT(c.contact[1], c.ticks / 10);  // the paths do press into the box
    // Convex: two planes only where the proxy sits on the line where two offset planes meet.
    EXPECT_LE(c.contact[2] + c.contact[3], c.ticks / 1000);
}

// From inside (the box as a room: concave edges and corners): never outside, and the paths
// reach edges (2 planes) and corners (3 planes).
TEST(Proxy, BoxRoomNeverOutsideReachesEdgesAndCorners) {
    const Counts c = runBoxPaths(kBox, true, 50000, [](const Vector3d& x) { return kBox.sdf(x); });
    std::cout << "room: ticks " << c.ticks << ", planes 0/1/2/3: " << c.contact[0] << "/"
              << c.contact[1] << "/" << c.contact[2] << "/" << c.contact[3] << ", farthest out "
              << c.worst << " m\n";
    EXPECT_GT(c.contact[1], 0);
    EXPECT_GT(c.contact[2], 0);
    EXPECT_GT(c.contact[3], 0);
}

// In a corner without friction the proxy is the corner point of the three offset planes.
TEST(Proxy, RoomCornerIsTheOffsetCornerPoint) {
    EmbreeScene scene;
    scene.addRigidMesh(boxMesh(kBox), kMaskSurface);
    scene.commit();
    ProxyParams params;
    params.staticFriction = params.dynamicFriction = 0;
    Proxy proxy(scene, params);
    proxy.reset(kBox.centre);
    const Vector3d corner = kBox.centre + kBox.half;
    const ProxyState& s = proxy.update(corner + Vector3d(3e-3, 1e-3, 2e-3), kNoForce, kK, kDt);
    EXPECT_EQ(s.contactCount, 3);
    EXPECT_NEAR((s.position - (corner - Vector3d::Constant(params.epsilon))).norm(), 0, 1e-9);
    // Along the edge x = y = max: the line of two planes.
    const ProxyState& e = proxy.update(corner + Vector3d(1e-3, 2e-3, -3e-3), kNoForce, kK, kDt);
    EXPECT_EQ(e.contactCount, 2);
    EXPECT_NEAR((e.position - (corner + Vector3d(-params.epsilon, -params.epsilon, -3e-3))).norm(),
                0, 1e-9);
}

// ---- 4. Free space and bad input ----

TEST(Proxy, FreeSpaceProxyIsTheProbe) {
    EmbreeScene empty;
    Proxy proxy(empty, ProxyParams{});
    proxy.reset({0, 0, 0});
    const ProxyState& s = proxy.update({1e-3, -2e-3, 3e-3}, kNoForce, kK, kDt);
    EXPECT_EQ(s.position, Vector3d(1e-3, -2e-3, 3e-3));
    EXPECT_EQ(s.contactCount, 0);
    EXPECT_NEAR((s.velocity - Vector3d(1, -2, 3)).norm(), 0, 1e-12);
    // Geometry of another mask does not stop the proxy.
    EmbreeScene bone;
    bone.addRigidMesh(planeQuad(1.0), palp::kernels::kMaskBone);
    bone.commit();
    Proxy p2(bone, ProxyParams{});
    p2.reset({0, 0, 1e-3});
    EXPECT_EQ(p2.update({0, 0, -1e-3}, kNoForce, kK, kDt).position, Vector3d(0, 0, -1e-3));
}

TEST(Proxy, NonFiniteInputLeavesTheStateUnchanged) {
    PlaneScene ps;
    Proxy proxy(ps.scene, ProxyParams{});
    proxy.reset({0, 0, 1e-3});
    proxy.update({1e-4, 0, -1e-3}, kNoForce, kK, kDt);
    const ProxyState before = proxy.state();
    ASSERT_EQ(before.contactCount, 1);
    const double nan = std::numeric_limits<double>::quiet_NaN();
    const double inf = std::numeric_limits<double>::infinity();
    const auto same = [&](const ProxyState& s) {
        EXPECT_EQ(s.position, before.position);
        EXPECT_EQ(s.velocity, before.velocity);
        EXPECT_EQ(s.contactCount, before.contactCount);
        EXPECT_EQ(s.normals[0], before.normals[0]);
        EXPECT_EQ(s.sticking, before.sticking);
    };
    same(proxy.update({nan, 0, 0}, kNoForce, kK, kDt));
    same(proxy.update({0, inf, 0}, kNoForce, kK, kDt));
    same(proxy.update({5e-3, 0, -1e-3}, Vector3d(nan, 0, 0), kK, kDt));
    same(proxy.update({5e-3, 0, -1e-3}, kNoForce, nan, kDt));
    same(proxy.update({5e-3, 0, -1e-3}, kNoForce, -kK, kDt));
    same(proxy.update({5e-3, 0, -1e-3}, kNoForce, kK, inf));
    same(proxy.update({5e-3, 0, -1e-3}, kNoForce, kK, 0.0));
}

// ---- 5. Real-time: no allocation ----

TEST(Proxy, NoAllocationInContact) {
    PlaneScene ps;
    Proxy proxy(ps.scene, ProxyParams{});
    proxy.reset({0, 0, 1e-3});
    proxy.update({0, 0, -1e-3}, kNoForce, kK, kDt);
    long contacts = 0, slips = 0;
    const std::uint64_t before = palp::test::allocationCount();
    for (int i = 0; i < 10000; ++i) {
        const double a = 1e-3 * i;
        const Vector3d probe(5e-3 * std::cos(a), 5e-3 * std::sin(a), -1e-3);
        const ProxyState& s = proxy.update(probe, Vector3d(0.01 * std::sin(3 * a), 0, 0), kK, kDt);
        contacts += s.contactCount;
        slips += !s.sticking;
    }
    const std::uint64_t after = palp::test::allocationCount();
    EXPECT_EQ(after - before, 0u);
    EXPECT_EQ(contacts, 10000);
    EXPECT_GT(slips, 100);
}

// ---- 6. Parameters ----

TEST(Proxy, BadParametersNameTheField) {
    EXPECT_NO_THROW(palp::haptics::validateProxyParams(ProxyParams{}));
    const auto expectThrow = [](ProxyParams p, const std::string& field) {
        try {
            palp::haptics::validateProxyParams(p);
            ADD_FAILURE() << field << ": no throw";
        } catch (const palp::ValueError& e) {
            EXPECT_NE(std::string(e.what()).find(field), std::string::npos) << e.what();
        }
    };
    ProxyParams p;
    p.staticFriction = -0.1;
    expectThrow(p, "staticFriction");
    p = {};
    p.staticFriction = std::numeric_limits<double>::quiet_NaN();
    expectThrow(p, "staticFriction");
    p = {};
    p.dynamicFriction = 0.6;  // > mu_s = 0.5
    expectThrow(p, "dynamicFriction");
    p = {};
    p.dynamicFriction = -1;
    expectThrow(p, "dynamicFriction");
    p = {};
    p.epsilon = 0;
    expectThrow(p, "epsilon");
    p = {};
    p.epsilon = std::numeric_limits<double>::infinity();
    expectThrow(p, "epsilon");
    p = {};
    p.maxIterations = 0;
    expectThrow(p, "maxIterations");
    p.maxIterations = 17;
    expectThrow(p, "maxIterations");
}

}  // namespace
