// The god-object proxy with Coulomb friction (docs/algorithms.md section 1).
#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <iomanip>
#include <iostream>
#include <limits>
#include <numbers>
#include <random>
#include <string>
#include <utility>
#include <vector>

#include "alloc_counter.h"
#include "palp/base/error.h"
#include "palp/haptics/proxy.h"
#include "palp/haptics/trajectory.h"
#include "palp/volume/mesh.h"
#include "palp/volume/phantom.h"
#include "ray_test_shapes.h"

namespace {

using Eigen::Vector3d;
using palp::haptics::Proxy;
using palp::haptics::ProxyParams;
using palp::haptics::ProxyState;
using palp::kernels::EmbreeScene;
using palp::kernels::intersectOne;
using palp::kernels::kMaskSurface;
using palp::kernels::MeshHit;
using palp::kernels::TriangleMesh;

constexpr double kK = 1000.0;  // N/m
constexpr double kDt = 1e-3;   // s
const Vector3d kNoForce = Vector3d::Zero();

void addVertex(TriangleMesh& m, const Vector3d& p) {
    for (int a = 0; a < 3; ++a) m.positions.push_back(static_cast<float>(p[a]));
}

/// The plane z = 0 as a square quad of half-width @p half (two triangles).
TriangleMesh planeQuad(double half) {
    TriangleMesh m;
    addVertex(m, {-half, -half, 0});
    addVertex(m, {half, -half, 0});
    addVertex(m, {half, half, 0});
    addVertex(m, {-half, half, 0});
    m.indices = {0, 1, 2, 0, 2, 3};
    return m;
}

/// The closed surface of @p box: 8 vertices, 12 triangles (winding as it comes: the proxy
/// orients faces by the side it approaches from).
TriangleMesh boxMesh(const palp::test::Box& box) {
    TriangleMesh m;
    for (int i = 0; i < 8; ++i) {
        const Vector3d s((i & 1) ? 1 : -1, (i & 2) ? 1 : -1, (i & 4) ? 1 : -1);
        addVertex(m, box.centre + box.half.cwiseProduct(s));
    }
    // Faces -x, +x, -y, +y, -z, +z as quads of corner indices.
    const int quads[6][4] = {{0, 2, 6, 4}, {1, 5, 7, 3}, {0, 4, 5, 1},
                             {2, 3, 7, 6}, {0, 1, 3, 2}, {4, 6, 7, 5}};
    for (const auto& q : quads)
        for (const int k : {q[0], q[1], q[2], q[0], q[2], q[3]})
            m.indices.push_back(static_cast<std::uint32_t>(k));
    return m;
}

struct PlaneScene {
    EmbreeScene scene;
    PlaneScene() {
        scene.addRigidMesh(planeQuad(1.0), kMaskSurface);
        scene.commit();
    }
};

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

// ---- 3. Iso-surface of a sphere volume ----

/// Distance from @p p to triangle abc (Ericson, Real-Time Collision Detection, 5.1.5).
double pointTriangleDistance(const Vector3d& p, const Vector3d& a, const Vector3d& b,
                             const Vector3d& c) {
    const Vector3d ab = b - a, ac = c - a, ap = p - a;
    const double d1 = ab.dot(ap), d2 = ac.dot(ap);
    if (d1 <= 0 && d2 <= 0) return (p - a).norm();
    const Vector3d bp = p - b;
    const double d3 = ab.dot(bp), d4 = ac.dot(bp);
    if (d3 >= 0 && d4 <= d3) return (p - b).norm();
    const double vc = d1 * d4 - d3 * d2;
    if (vc <= 0 && d1 >= 0 && d3 <= 0) return (p - (a + d1 / (d1 - d3) * ab)).norm();
    const Vector3d cp = p - c;
    const double d5 = ab.dot(cp), d6 = ac.dot(cp);
    if (d6 >= 0 && d5 <= d6) return (p - c).norm();
    const double vb = d5 * d2 - d1 * d6;
    if (vb <= 0 && d2 >= 0 && d6 <= 0) return (p - (a + d2 / (d2 - d6) * ac)).norm();
    const double va = d3 * d6 - d5 * d4;
    if (va <= 0 && (d4 - d3) >= 0 && (d5 - d6) >= 0)
        return (p - (b + (d4 - d3) / ((d4 - d3) + (d5 - d6)) * (c - b))).norm();
    const double denom = 1 / (va + vb + vc);
    return (p - (a + ab * (vb * denom) + ac * (vc * denom))).norm();
}

TEST(Proxy, SphereIsoSurfaceStaysOutside) {
    const palp::test::Sphere sphere{Vector3d(0.11e-3, -0.23e-3, 0.05e-3), 4e-3};
    auto grid = palp::test::shapeVolume([&](const Vector3d& x) { return sphere.sdf(x); },
                                        {-12, -12, -12}, {12, 12, 12});
    const TriangleMesh mesh = palp::volume::isoSurface(*grid, palp::test::kIso);
    ASSERT_GT(mesh.triangleCount(), 500u);
    // Faceting tolerance: how far inside the sphere the mesh reaches. A point outside the
    // (star-shaped) mesh is at least the mesh's distance from the centre.
    double minDist = std::numeric_limits<double>::infinity();
    for (std::size_t t = 0; t < mesh.triangleCount(); ++t) {
        Vector3d v[3];
        for (int k = 0; k < 3; ++k) {
            const std::size_t i = 3 * mesh.indices[3 * t + static_cast<std::size_t>(k)];
            v[k] = Vector3d(mesh.positions[i], mesh.positions[i + 1], mesh.positions[i + 2]);
        }
        minDist = std::min(minDist, pointTriangleDistance(sphere.centre, v[0], v[1], v[2]));
    }
    const double tol = std::max(0.0, sphere.radius - minDist) + 1e-9;
    ASSERT_LT(tol, 0.1e-3);
    EmbreeScene scene;
    scene.addRigidMesh(mesh, kMaskSurface);
    scene.commit();
    std::mt19937 rng(5);
    std::uniform_real_distribution<double> uni(-1, 1), unit(0, 1);
    long contacts = 0, ticks = 0;
    double deepestProbe = 0;
    for (int path = 0; path < 40; ++path) {
        ProxyParams params;
        if (path % 2) params.staticFriction = params.dynamicFriction = 0;
        Proxy proxy(scene, params);
        Vector3d dir(uni(rng), uni(rng), uni(rng));
        dir.normalize();
        Vector3d probe = sphere.centre + 6e-3 * dir;
        proxy.reset(probe);
        Vector3d lastN = Vector3d::Zero(), lastT1 = proxy.state().tangent1;
        Vector3d lastT2 = proxy.state().tangent2;
        for (int i = 0; i < 500; ++i) {
            // Toward a point up to 2.5 mm deep under a wandering surface point.
            Vector3d wander(uni(rng), uni(rng), uni(rng));
            dir = (dir + 0.05 * wander).normalized();
            const double depth = 2.5e-3 * unit(rng) - 0.5e-3;
            const Vector3d goal = sphere.centre + (sphere.radius - depth) * dir;
            const Vector3d stepv = goal - probe;
            probe += stepv.norm() > 1e-3 ? Vector3d(1e-3 * stepv.normalized()) : stepv;
            const ProxyState& s = proxy.update(probe, kNoForce, kK, kDt);
            ++ticks;
            contacts += s.contactCount > 0;
            deepestProbe = std::max(deepestProbe, -sphere.sdf(probe));
            ASSERT_GE(sphere.sdf(s.position), -tol)
                << "path " << path << " tick " << i << " proxy " << s.position.transpose();
            ASSERT_LE(s.queries, 2 * (params.maxIterations + 1));
            // The tangent frame turns with the normal, no faster (|dt1| <= ~|dn|).
            if (s.contactCount > 0 && lastN != Vector3d::Zero()) {
                const double dn = (s.normals[0] - lastN).norm();
                ASSERT_LE((s.tangent1 - lastT1).norm(), 2 * dn + 1e-12);
                ASSERT_LE((s.tangent2 - lastT2).norm(), 4 * dn + 1e-12);
                ASSERT_NEAR(s.tangent1.dot(s.normals[0]), 0, 1e-12);
            }
            lastN = s.contactCount > 0 ? s.normals[0] : Vector3d::Zero();
            lastT1 = s.tangent1;
            lastT2 = s.tangent2;
        }
    }
    std::cout << "sphere: tolerance " << tol << " m, ticks " << ticks << ", in contact " << contacts
              << ", deepest probe " << deepestProbe << " m\n";
    EXPECT_GT(contacts, ticks / 4);
    EXPECT_GT(deepestProbe, 1.5e-3);
}

// ---- 3b. Faceted surfaces: concave facet junctions and a noisy scan iso-surface ----

/// Two facets meeting in a shallow concave fold along x = 0: z = 0 for x < 0 and
/// z = x tan(angle) for x > 0 (10 mm wide each).
TriangleMesh foldMesh(double angle) {
    TriangleMesh m;
    const double h = 10e-3, rise = h * std::tan(angle);
    addVertex(m, {-h, -h, 0});
    addVertex(m, {0, -h, 0});
    addVertex(m, {0, h, 0});
    addVertex(m, {-h, h, 0});
    addVertex(m, {h, -h, rise});
    addVertex(m, {h, h, rise});
    m.indices = {0, 1, 2, 0, 2, 3, 1, 4, 5, 1, 5, 2};
    return m;
}

// A proxy left on the flat facet's offset plane just past a concave fold is closer than
// epsilon to the rising facet, i.e. below that facet's offset plane (it stays there: the
// proxy does not move up while it sticks). It is held by that facet and must report it as
// its contact plane, sticking; without friction it slides onto the facet's offset plane.
TEST(Proxy, StuckPastAConcaveFoldReportsTheFacet) {
    const double angle =
        2.0 * std::numbers::pi / 180;  // iso-surface facets of a noisy scan tilt ~1-2 deg
    EmbreeScene scene;
    scene.addRigidMesh(foldMesh(angle), kMaskSurface);
    scene.commit();
    const Vector3d nB = Vector3d(-std::sin(angle), 0, std::cos(angle));  // rising facet, outward
    ProxyParams params;
    const double eps = params.epsilon;
    const Vector3d start(0.1e-3, 0, eps);  // on the flat facet's offset plane, past the fold
    const double gap = nB.dot(start);      // distance to the rising facet
    ASSERT_LT(gap, eps * (1 - 1e-3));
    ASSERT_GT(gap, 0.0);
    const Vector3d probe(0.1e-3, 0, -1e-3);  // pressed straight down: inside the cone (2 deg)

    Proxy sticky(scene, params);
    sticky.reset(start);
    const ProxyState& s = sticky.update(probe, kNoForce, kK, kDt);
    EXPECT_EQ(s.position, start);  // stuck where it was
    ASSERT_EQ(s.contactCount, 1);
    EXPECT_TRUE(s.sticking);
    EXPECT_NEAR((s.normals[0] - nB).norm(), 0, 1e-6);
    EXPECT_NEAR(std::abs(s.tangent1.dot(s.normals[0])), 0, 1e-12);

    params.staticFriction = params.dynamicFriction = 0;
    Proxy slippery(scene, params);
    slippery.reset(start);
    const ProxyState& f = slippery.update(probe, kNoForce, kK, kDt);
    ASSERT_EQ(f.contactCount, 1);
    EXPECT_FALSE(f.sticking);
    // The probe projected onto the rising facet's offset plane nB.x = eps.
    const Vector3d goal = probe + (eps - nB.dot(probe)) * nB;
    EXPECT_NEAR((f.position - goal).norm(), 0, 1e-9);
}

/// Whether @p p lies inside the closed mesh of @p scene: parity of the crossings along three
/// generic rays, by majority (a ray through a shared edge can miscount).
bool insideMesh(const EmbreeScene& scene, const Vector3d& p) {
    static const std::array<Vector3d, 3> kDirs = {Vector3d(0.267261, 0.534522, 0.801784),
                                                  Vector3d(-0.639602, 0.426401, 0.639602),
                                                  Vector3d(0.562254, -0.749672, 0.349215)};
    int votes = 0;
    for (const Vector3d& d : kDirs) {
        int crossings = 0;
        float tnear = 0;
        for (int i = 0; i < 1000; ++i) {
            MeshHit hit;
            if (!intersectOne(scene, p, d, tnear, std::numeric_limits<float>::infinity(),
                              kMaskSurface, hit))
                break;
            ++crossings;
            tnear = hit.t * (1.0f + 1e-6f) + 1e-7f;
        }
        votes += crossings % 2;
    }
    return votes >= 2;
}

// The skin of a converted scan: the AVC phantom rendered like a CT (1 mm voxels, 10 HU noise),
// meshed at -500 HU like Scene::fromVolume. Noise tilts every facet by a degree or so, so a
// proxy dragged over it keeps meeting concave facet junctions. A raster (as `palp palpate`
// runs it) must never put the proxy inside the skin, and whenever the proxy is held back
// from the probe it must report a contact plane (before the fix: ~20 % of such ticks had none
// at 1 mm voxels, ~38 % at 0.5 mm).
TEST(Proxy, NoisyScanIsoSurfaceKeepsContactAndNeverPenetrates) {
    palp::volume::PhantomSpec spec;
    spec.params.scene = palp::volume::PhantomScene::Avc;
    spec.params.quadrant = 2;
    spec.voxelSize = 1e-3;
    spec.noiseSigmaHu = 10;
    spec.seed = 7;
    const palp::volume::Volume volume = palp::volume::makePhantomVolume(spec);
    const TriangleMesh mesh = palp::volume::isoSurface(*volume.grid, -500.0);
    ASSERT_GT(mesh.triangleCount(), 10000u);
    // The skin is closed (also at the volume's edge) and manifold: every edge in two triangles.
    std::vector<std::pair<std::uint32_t, std::uint32_t>> edges;
    for (std::size_t t = 0; t < mesh.triangleCount(); ++t)
        for (std::size_t k = 0; k < 3; ++k) {
            const std::uint32_t a = mesh.indices[3 * t + k], b = mesh.indices[3 * t + (k + 1) % 3];
            edges.emplace_back(std::min(a, b), std::max(a, b));
        }
    std::sort(edges.begin(), edges.end());
    for (std::size_t i = 0; i < edges.size(); i += 2) {
        ASSERT_TRUE(i + 1 < edges.size() && edges[i] == edges[i + 1] &&
                    (i + 2 >= edges.size() || edges[i + 2] != edges[i]))
            << "edge " << edges[i].first << "-" << edges[i].second << " not shared by 2";
    }
    // How far the noisy iso-surface lies from the analytic skin y = 0 under the raster.
    double meshTop = -std::numeric_limits<double>::infinity();
    for (std::size_t i = 0; i < mesh.positions.size(); i += 3) {
        if (std::abs(mesh.positions[i]) < 0.03 && std::abs(mesh.positions[i + 2]) < 0.03 &&
            mesh.positions[i + 1] < 0.005)
            meshTop = std::max(meshTop, static_cast<double>(mesh.positions[i + 1]));
    }
    ASSERT_LT(meshTop, 0.5 * spec.voxelSize);
    EmbreeScene scene;
    scene.addRigidMesh(mesh, kMaskSurface);
    scene.commit();

    palp::haptics::RasterTrajectory raster;
    raster.centre = Vector3d(-5e-3, 0, 5e-3);
    raster.extentU = 0.04;
    raster.extentV = 0.008;
    raster.lineSpacingM = 1e-3;
    raster.speedMps = 0.1;
    for (const double mu : {0.5, 0.0}) {
        for (const double depth : {2e-3, 4e-3}) {
            ProxyParams params;
            params.staticFriction = mu;
            params.dynamicFriction = 0.6 * mu;
            Proxy proxy(scene, params);
            raster.depthM = depth;
            Vector3d probe, velocity;
            palp::haptics::sampleTrajectory(raster, 0.0, probe, velocity);
            proxy.reset(probe);
            const auto ticks = static_cast<int>(raster.durationSeconds() / kDt);
            long pressing = 0, noContact = 0, sticking = 0, inside = 0;
            double deepest = -std::numeric_limits<double>::infinity();
            for (int i = 1; i <= ticks; ++i) {
                palp::haptics::sampleTrajectory(raster, i * kDt, probe, velocity);
                const ProxyState& s = proxy.update(probe, kNoForce, 300.0, kDt);
                deepest = std::max(deepest, s.position.y());
                inside += insideMesh(scene, s.position);
                if ((probe - s.position).norm() > 1e-6) {
                    ++pressing;
                    noContact += s.contactCount == 0;
                    sticking += s.sticking;
                }
            }
            std::cout << "noisy skin mu " << mu << " depth " << depth << ": ticks " << ticks
                      << ", pressing " << pressing << ", no contact plane " << noContact
                      << ", sticking " << sticking << ", inside " << inside << ", deepest proxy y "
                      << deepest << " m (mesh top " << meshTop << ")\n";
            EXPECT_GT(pressing, ticks / 2);
            EXPECT_EQ(inside, 0);
            EXPECT_LE(deepest, meshTop);
            EXPECT_LE(noContact, pressing / 1000) << "mu " << mu << " depth " << depth;
            if (mu > 0) {
                EXPECT_GT(sticking, pressing / 10);
            }
        }
    }
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
