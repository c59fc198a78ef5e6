// The god-object proxy on curved and faceted surfaces: a sphere volume's iso-surface (never
// inside), a proxy stuck past a concave fold of two facets, and the noisy iso-surface of a
// scanned phantom under a raster (contact always reported, never penetrated).
#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <algorithm>
#include <array>
#include <cmath>
#include <iostream>
#include <limits>
#include <numbers>
#include <random>
#include <utility>
#include <vector>

#include "palp/haptics/devices/trajectory.h"
#include "palp/haptics/rendering/proxy.h"
#include "palp/volume/mesh.h"
#include "palp/volume/phantom.h"
#include "proxy_fixtures.h"
#include "ray_test_shapes.h"

namespace {

using namespace palp::haptics::pfix;  // Vector3d, Proxy*, kernels' mesh types, kK, kDt, meshes

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

}  // namespace
