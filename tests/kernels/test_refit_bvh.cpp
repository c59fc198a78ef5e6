// palp's refittable BVH (refit_bvh.h) and its Embree user geometry (EmbreeScene::addRefitMesh)
// against Embree's own robust triangle mesh on the same deforming meshes: identical hits, t,
// primID (up to ties on edges), u, v and Ng; watertightness on shared edges and vertices; refit
// equal to a fresh build, slack refits exact and local. The user geometry's ray forms, zero
// allocations, degenerate input and the tree's depth are in test_refit_bvh_queries.cpp.
#include <embree3/rtcore.h>
#include <gtest/gtest.h>

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <algorithm>
#include <array>
#include <cmath>
#include <random>
#include <vector>

#include "palp/base/error.h"
#include "palp/kernels/embree_scene.h"
#include "palp/kernels/refit_bvh.h"
#include "refit_bvh_fixtures.h"

namespace {

using namespace palp::kernels;
using namespace palp::kernels::rfix;

/// Embree's reference: a robust deforming triangle mesh, updated and committed per step.
struct Reference {
    EmbreeScene scene{/*robust=*/true};
    unsigned geom;
    explicit Reference(const TriangleMesh& m) : geom(scene.addDeformingMesh(m, kMaskSurface)) {
        scene.commit();
    }
    void update(const std::vector<float>& p) {
        ASSERT_TRUE(scene.updateVertices(geom, p));
        scene.commit();
    }
};

/// Smallest barycentric coordinate of a hit: ~0 on an edge, where two triangles tie.
float edgeDistance(float u, float v) { return std::min({u, v, 1.0f - u - v}); }

struct Mismatch {
    int hitMiss = 0, t = 0, prim = 0, primTie = 0, uv = 0, ng = 0, hits = 0;
};

/// One ray against the palp mesh (directly and through Embree) and the reference.
void compareRay(const RefitMesh& mesh, RTCScene palpScene, unsigned palpGeom, RTCScene ref,
                const Vec3f& o, const Vec3f& d, float tfar, Mismatch& mm) {
    RTCRayHit rr, pr;
    const bool refHit = trace(ref, o, d, 0.0f, tfar, kMaskAll, rr);
    TriangleHit h;
    const bool direct = mesh.intersect(o, d, 0.0f, tfar, h);
    const bool viaEmbree = trace(palpScene, o, d, 0.0f, tfar, kMaskAll, pr);
    if (direct != refHit || viaEmbree != refHit) {
        ++mm.hitMiss;
        return;
    }
    if (!refHit) return;
    ++mm.hits;
    // The user geometry reports exactly what the mesh does.
    EXPECT_EQ(pr.hit.geomID, palpGeom);
    EXPECT_EQ(pr.hit.primID, h.primId);
    EXPECT_EQ(pr.ray.tfar, h.t);
    EXPECT_EQ(pr.hit.u, h.u);
    EXPECT_EQ(pr.hit.Ng_x, h.ng[0]);
    // The triangle in double: the conditioning of the plane intersection is 1 / |cos| of the
    // angle between ray and normal; both Embree and palp err by about eps / |cos| from the exact
    // answer, so grazing rays get that much more room.
    const float* pos = mesh.positions().data();
    std::array<Eigen::Vector3d, 3> x;
    for (std::size_t k = 0; k < 3; ++k) {
        const std::size_t vi = mesh.indices()[3 * h.primId + k];
        x[k] = Eigen::Vector3d(pos[3 * vi], pos[3 * vi + 1], pos[3 * vi + 2]);
    }
    const Eigen::Vector3d e1 = x[1] - x[0], e2 = x[2] - x[0], n = e1.cross(e2);
    const Eigen::Vector3d dd(d[0], d[1], d[2]);
    const double cosine = std::abs(n.normalized().dot(dd.normalized()));
    if (std::abs(h.t - rr.ray.tfar) > 1e-6 * rr.ray.tfar / std::max(cosine, 1e-3)) ++mm.t;
    if (h.primId != rr.hit.primID) {
        // A tie: both hit points on the shared edge or vertex of two triangles.
        if (edgeDistance(h.u, h.v) < 1e-4f && edgeDistance(rr.hit.u, rr.hit.v) < 1e-4f)
            ++mm.primTie;
        else
            ++mm.prim;
        return;
    }
    // Same triangle: the hit points from (u, v) agree as t does; Ng to the rounding of a cross
    // product of the edges (thin triangles lose digits to cancellation).
    const auto point = [&](float u, float v) { return x[0] + u * e1 + v * e2; };
    const double dist = (point(h.u, h.v) - point(rr.hit.u, rr.hit.v)).norm();
    if (dist > 1e-6 * h.t * dd.norm() / std::max(cosine, 1e-3)) ++mm.uv;
    const Eigen::Vector3d a(h.ng[0], h.ng[1], h.ng[2]), b(rr.hit.Ng_x, rr.hit.Ng_y, rr.hit.Ng_z);
    // Embree's robust test forms Ng from vertices relative to the ray origin, so its rounding
    // scales with the distance to the triangle.
    const double reach = (x[0] - Eigen::Vector3d(o[0], o[1], o[2])).norm() + e1.norm();
    if ((a - b).norm() > 16 * 1.2e-7 * reach * (e1.norm() + e2.norm())) ++mm.ng;
}

TEST(RefitMesh, MatchesEmbreeTrianglesOnDeformingMeshes) {
    for (const Shape& s : shapes()) {
        RefitMesh mesh(s.mesh);
        EmbreeScene palp(/*robust=*/true);
        const unsigned geom = palp.addRefitMesh(mesh, kMaskSurface, static_cast<float>(s.size));
        palp.commit();
        Reference ref(s.mesh);
        RandomRays rays(11, s.centre, 3 * s.size, 1.2 * s.size);
        Mismatch mm;
        for (int step = 0; step < 6; ++step) {
            if (step > 0) {
                const std::vector<float> p = deformed(s.mesh, s.centre, s.size, 1.0, step);
                ASSERT_EQ(mesh.refit(p), RefitStatus::Ok) << s.name;
                ref.update(p);
            }
            for (int r = 0; r < 2000; ++r) {
                Vec3f o, d;
                float tfar;
                rays.next(o, d, tfar);
                compareRay(mesh, palp.handle(), geom, ref.scene.handle(), o, d, tfar, mm);
            }
        }
        EXPECT_GT(mm.hits, 6000) << s.name;
        EXPECT_EQ(mm.hitMiss, 0) << s.name;
        EXPECT_EQ(mm.t, 0) << s.name;
        EXPECT_EQ(mm.prim, 0) << s.name << " (ties on edges: " << mm.primTie << ")";
        EXPECT_LE(mm.primTie, mm.hits / 1000) << s.name;
        EXPECT_EQ(mm.uv, 0) << s.name;
        EXPECT_EQ(mm.ng, 0) << s.name;
    }
}

// Rays aimed exactly at the vertices and at points of the edges of closed meshes (float
// targets on the edge to rounding), and axis-aligned rays along the grid lines of a box, where a
// non-watertight test lets rays slip through: every one hits, at or before the target.
TEST(RefitMesh, WatertightOnSharedEdgesAndVertices) {
    for (const Shape& s : shapes()) {
        for (int step = 0; step < 2; ++step) {
            RefitMesh mesh(s.mesh);
            const std::vector<float> p =
                step == 0 ? s.mesh.positions : deformed(s.mesh, s.centre, s.size, 1.0, 3);
            ASSERT_NE(mesh.refit(p), RefitStatus::Rejected);
            std::mt19937 rng(5);
            std::normal_distribution<double> g;
            std::uniform_real_distribution<float> along(0, 1);
            int rays = 0, misses = 0, late = 0;
            // Vertex normals of the (deformed) surface.
            std::vector<Eigen::Vector3d> normal(s.mesh.vertexCount(), Eigen::Vector3d::Zero());
            const auto vert = [&](std::uint32_t i) {
                return Eigen::Vector3f(p[3 * i], p[3 * i + 1], p[3 * i + 2]);
            };
            for (std::size_t t = 0; t < s.mesh.triangleCount(); ++t) {
                const std::uint32_t* i = &s.mesh.indices[3 * t];
                const Eigen::Vector3d n = (vert(i[1]) - vert(i[0]))
                                              .cast<double>()
                                              .cross((vert(i[2]) - vert(i[0])).cast<double>());
                for (int k = 0; k < 3; ++k) normal[i[k]] += n;
            }
            // From outside along the outward surface normal at the target (a little jitter),
            // so the ray crosses the surface there, at t = 1, or hits it before.
            const auto shoot = [&](const Eigen::Vector3f& target, const Eigen::Vector3d& out) {
                const Eigen::Vector3d jitter = Eigen::Vector3d(g(rng), g(rng), g(rng)) * 0.1;
                const Eigen::Vector3d from =
                    target.cast<double>() + 3 * s.size * (out.normalized() + jitter).normalized();
                const Vec3f o = {static_cast<float>(from.x()), static_cast<float>(from.y()),
                                 static_cast<float>(from.z())};
                const Vec3f d = {target.x() - o[0], target.y() - o[1], target.z() - o[2]};
                TriangleHit h;
                ++rays;
                if (!mesh.intersect(o, d, 0.0f, 2.0f, h))
                    ++misses;
                else if (h.t > 1.0f + 1e-5f)
                    ++late;
            };
            for (std::size_t t = 0; t < s.mesh.triangleCount(); ++t) {
                const std::uint32_t ia = s.mesh.indices[3 * t], ib = s.mesh.indices[3 * t + 1];
                const Eigen::Vector3f a = vert(ia), b = vert(ib);
                const float w = along(rng);
                shoot(a, normal[ia]);
                shoot(a + w * (b - a),
                      (1 - w) * normal[ia].normalized() + w * normal[ib].normalized());
                shoot(0.5f * (a + b), normal[ia].normalized() + normal[ib].normalized());
            }
            EXPECT_EQ(rays, 3 * static_cast<int>(s.mesh.triangleCount()));
            EXPECT_EQ(misses, 0) << s.name << " step " << step;
            EXPECT_EQ(late, 0) << s.name << " step " << step;
        }
    }
    // Axis-aligned rays exactly along the grid lines of the rest box (through its vertices and
    // edges), from every side.
    const Shape box = shapes()[2];
    RefitMesh mesh(box.mesh);
    int misses = 0, rays = 0;
    const float lo = static_cast<float>(box.centre.x() - 0.02);
    for (std::size_t v = 0; v < box.mesh.vertexCount(); ++v) {
        for (std::size_t a = 0; a < 3; ++a) {
            for (float sign : {-1.0f, 1.0f}) {
                Vec3f o = {box.mesh.positions[3 * v], box.mesh.positions[3 * v + 1],
                           box.mesh.positions[3 * v + 2]};
                Vec3f d = {0, 0, 0};
                d[a] = sign;
                o[a] -= sign * 0.1f;  // well outside, on the same grid line
                TriangleHit h;
                ++rays;
                if (!mesh.intersect(o, d, 0.0f, kInfF, h)) ++misses;
            }
        }
    }
    EXPECT_GT(rays, 5000);
    EXPECT_EQ(misses, 0) << "grid-line rays (box from " << lo << ")";
}

// A refit after a large deformation (twice the size, twisted, dented) answers exactly as a fresh
// build on the deformed positions: the hierarchy only prunes, never decides.
TEST(RefitMesh, RefitAfterLargeDeformationEqualsFreshBuild) {
    for (const Shape& s : shapes()) {
        RefitMesh refitted(s.mesh);
        TriangleMesh moved = s.mesh;
        for (int step = 1; step <= 3; ++step) {
            moved.positions = deformed(s.mesh, s.centre, s.size, 2.5, step);
            ASSERT_EQ(refitted.refit(moved.positions), RefitStatus::Ok);
        }
        const RefitMesh fresh(moved);
        // Bounds equal too: refit boxes are exact unions.
        EXPECT_EQ(refitted.bounds().lo, fresh.bounds().lo);
        EXPECT_EQ(refitted.bounds().hi, fresh.bounds().hi);
        RandomRays rays(3, s.centre, 4 * s.size, 1.5 * s.size);
        int hits = 0;
        for (int r = 0; r < 5000; ++r) {
            Vec3f o, d;
            float tfar;
            rays.next(o, d, tfar);
            TriangleHit a, b;
            const bool ha = refitted.intersect(o, d, 0.0f, tfar, a);
            ASSERT_EQ(ha, fresh.intersect(o, d, 0.0f, tfar, b)) << s.name << " ray " << r;
            ASSERT_EQ(refitted.occluded(o, d, 0.0f, tfar), ha);
            if (!ha) continue;
            ++hits;
            EXPECT_EQ(a.t, b.t);
            if (a.primId != b.primId) {
                EXPECT_LT(edgeDistance(a.u, a.v), 1e-4f);
            } else {
                EXPECT_EQ(a.ng, b.ng);
            }
        }
        EXPECT_GT(hits, 2500) << s.name;
    }
}

// A slack refit touches only the nodes above vertices that moved beyond the slack, and its
// queries equal an exact refit's on the same positions: a local press grown in small steps
// (some below the slack, some above) over a far field drifting well below it.
TEST(RefitMesh, SlackRefitIsExactForQueriesAndLocal) {
    const Shape s = shapes()[2];  // hex13: a tissue surface
    const float slack = static_cast<float>(0.02 * s.size);
    RefitMesh loose(s.mesh);
    loose.setRefitSlack(slack);
    RefitMesh exact(s.mesh);
    EXPECT_THROW(exact.setRefitSlack(-1e-3f), palp::ValueError);
    EXPECT_THROW(exact.setRefitSlack(kNan), palp::ValueError);
    std::mt19937 rng(5);
    std::uniform_real_distribution<double> noise(-1, 1);
    const Eigen::Vector3d press = s.centre + Eigen::Vector3d(0, s.size, 0);  // top face centre
    std::vector<float> x = s.mesh.positions;
    std::size_t touched = 0;
    int steps = 0;
    RandomRays rays(11, s.centre, 4 * s.size, 1.2 * s.size);
    for (int step = 1; step <= 40; ++step) {
        const double depth = 0.3 * s.size * step / 40;  // 0.3 slack per step: local refits
        for (std::size_t v = 0; v < s.mesh.vertexCount(); ++v) {
            const Eigen::Vector3d p(s.mesh.positions[3 * v], s.mesh.positions[3 * v + 1],
                                    s.mesh.positions[3 * v + 2]);
            const double r2 = (p - press).squaredNorm() / (0.15 * s.size * 0.15 * s.size);
            const double dy = -depth * std::exp(-r2) + 0.2 * slack * noise(rng);
            x[3 * v + 1] = static_cast<float>(p.y() + dy);
        }
        ASSERT_EQ(loose.refit(x), RefitStatus::Ok);
        ASSERT_EQ(exact.refit(x), RefitStatus::Ok);
        touched += loose.lastRefitNodes();
        ++steps;
        EXPECT_EQ(exact.lastRefitNodes(), exact.nodeCount());
        // The root box holds the mesh, at most the slack (and rounding) looser than exact.
        for (std::size_t k = 0; k < 3; ++k) {
            EXPECT_LE(loose.bounds().lo[k], exact.bounds().lo[k]);
            EXPECT_GE(loose.bounds().lo[k], exact.bounds().lo[k] - 1.01f * slack);
            EXPECT_GE(loose.bounds().hi[k], exact.bounds().hi[k]);
        }
        for (int r = 0; r < 400; ++r) {
            Vec3f o, d;
            float tfar;
            rays.next(o, d, tfar);
            TriangleHit a, b;
            const bool ha = loose.intersect(o, d, 0.0f, tfar, a);
            ASSERT_EQ(ha, exact.intersect(o, d, 0.0f, tfar, b)) << "step " << step << " ray " << r;
            ASSERT_EQ(loose.occluded(o, d, 0.0f, tfar), ha);
            if (!ha) continue;
            EXPECT_EQ(a.t, b.t);
            EXPECT_EQ(a.primId, b.primId);
        }
    }
    // The press reaches a small part of the surface: on average well under a tenth of the nodes
    // per refit (an exact refit recomputes all of them).
    EXPECT_LT(static_cast<double>(touched) / steps, 0.1 * static_cast<double>(loose.nodeCount()));
    EXPECT_GT(touched, 0u);
    // Moving nothing beyond the slack recomputes nothing; a large global move, everything.
    ASSERT_EQ(loose.refit(x), RefitStatus::Ok);
    EXPECT_EQ(loose.lastRefitNodes(), 0u);
    for (float& c : x) c += 3 * slack;
    ASSERT_EQ(loose.refit(x), RefitStatus::Ok);
    EXPECT_EQ(loose.lastRefitNodes(), loose.nodeCount());
    const RefitMesh fresh(TriangleMesh{x, s.mesh.indices});
    for (std::size_t k = 0; k < 3; ++k) EXPECT_LE(loose.bounds().lo[k], fresh.bounds().lo[k]);
}

TEST(RefitMesh, RefitOfTheMovedVerticesEqualsTheFullRefit) {
    const Shape s = shapes()[2];
    const float slack = static_cast<float>(0.02 * s.size);
    RefitMesh full(s.mesh), listed(s.mesh);
    full.setRefitSlack(slack);
    listed.setRefitSlack(slack);
    std::mt19937 rng(7);
    std::uniform_int_distribution<std::uint32_t> pick(
        0, static_cast<std::uint32_t>(s.mesh.vertexCount() - 1));
    std::uniform_real_distribution<float> move(-3 * slack, 3 * slack);
    std::vector<float> x = s.mesh.positions;
    RandomRays rays(13, s.centre, 4 * s.size, 1.2 * s.size);
    for (int step = 0; step < 30; ++step) {
        // A few vertices move (some twice, some listed twice), the others stay.
        std::vector<std::uint32_t> moved;
        for (int i = 0; i < 20; ++i) {
            const std::uint32_t v = pick(rng);
            for (std::size_t k = 0; k < 3; ++k) x[3 * v + k] += move(rng);
            moved.push_back(v);
            if (i % 7 == 0) moved.push_back(v);
        }
        ASSERT_EQ(full.refit(x), RefitStatus::Ok);
        ASSERT_EQ(listed.refit(x, moved), RefitStatus::Ok);
        EXPECT_EQ(listed.lastRefitNodes(), full.lastRefitNodes()) << "step " << step;
        for (std::size_t k = 0; k < 3; ++k) {
            EXPECT_EQ(listed.bounds().lo[k], full.bounds().lo[k]);
            EXPECT_EQ(listed.bounds().hi[k], full.bounds().hi[k]);
        }
        for (int r = 0; r < 200; ++r) {
            Vec3f o, d;
            float tfar;
            rays.next(o, d, tfar);
            TriangleHit a, b;
            const bool ha = listed.intersect(o, d, 0.0f, tfar, a);
            ASSERT_EQ(ha, full.intersect(o, d, 0.0f, tfar, b)) << "step " << step << " ray " << r;
            if (ha) {
                EXPECT_EQ(a.primId, b.primId);
            }
        }
    }
    // A listed vertex out of range or not finite: rejected, nothing taken.
    const std::vector<std::uint32_t> bad{static_cast<std::uint32_t>(s.mesh.vertexCount())};
    EXPECT_EQ(listed.refit(x, bad), RefitStatus::Rejected);
    std::vector<float> y = x;
    y[3] = kNan;
    const std::vector<std::uint32_t> one{1};
    EXPECT_EQ(listed.refit(y, one), RefitStatus::Rejected);
}

}  // namespace
