// palp's refittable BVH (refit_bvh.h) and its Embree user geometry (EmbreeScene::addRefitMesh)
// against Embree's own robust triangle mesh on the same deforming meshes: identical hits, t,
// primID (up to ties on edges), u, v and Ng; watertightness on shared edges and vertices; refit
// equal to a fresh build; zero allocations per refit and per query; degenerate input.
#include <embree3/rtcore.h>
#include <gtest/gtest.h>

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <algorithm>
#include <array>
#include <cmath>
#include <functional>
#include <limits>
#include <random>
#include <vector>

#include "alloc_counter.h"
#include "palp/base/error.h"
#include "palp/kernels/embree_scene.h"
#include "palp/kernels/refit_bvh.h"

namespace {

using namespace palp::kernels;
using Vec3f = std::array<float, 3>;

constexpr float kNan = std::numeric_limits<float>::quiet_NaN();
constexpr float kInfF = std::numeric_limits<float>::infinity();

/// Closed UV sphere (shared vertices, poles single vertices), outward winding.
TriangleMesh sphereMesh(const Eigen::Vector3d& c, double r, int rings, int segments) {
    TriangleMesh m;
    const auto add = [&](const Eigen::Vector3d& p) {
        for (int a = 0; a < 3; ++a) m.positions.push_back(static_cast<float>(p[a]));
    };
    add(c + Eigen::Vector3d(0, 0, r));
    for (int i = 1; i < rings; ++i) {
        const double th = M_PI * i / rings;
        for (int j = 0; j < segments; ++j) {
            const double ph = 2 * M_PI * j / segments;
            add(c + r * Eigen::Vector3d(std::sin(th) * std::cos(ph), std::sin(th) * std::sin(ph),
                                        std::cos(th)));
        }
    }
    add(c + Eigen::Vector3d(0, 0, -r));
    const auto ring = [&](int i, int j) {
        return static_cast<std::uint32_t>(1 + (i - 1) * segments + (j % segments));
    };
    const auto south = static_cast<std::uint32_t>(1 + (rings - 1) * segments);
    for (int j = 0; j < segments; ++j) {
        m.indices.insert(m.indices.end(), {0u, ring(1, j), ring(1, j + 1)});
        for (int i = 1; i + 1 < rings; ++i) {
            m.indices.insert(m.indices.end(), {ring(i, j), ring(i + 1, j), ring(i + 1, j + 1)});
            m.indices.insert(m.indices.end(), {ring(i, j), ring(i + 1, j + 1), ring(i, j + 1)});
        }
        m.indices.insert(m.indices.end(), {ring(rings - 1, j), south, ring(rings - 1, j + 1)});
    }
    return m;
}

/// Closed surface of a box of @p n nodes per axis (the boundary of an n^3 hex grid), spacing
/// @p h, from @p lo: 12 (n - 1)^2 triangles with shared vertices, outward winding.
TriangleMesh boxSurface(int n, double h, const Eigen::Vector3d& lo) {
    TriangleMesh m;
    std::vector<std::int64_t> id(static_cast<std::size_t>(n * n * n), -1);
    const auto vertex = [&](int i, int j, int k) {
        std::int64_t& v = id[static_cast<std::size_t>((k * n + j) * n + i)];
        if (v < 0) {
            v = static_cast<std::int64_t>(m.vertexCount());
            const Eigen::Vector3d p = lo + h * Eigen::Vector3d(i, j, k);
            for (int a = 0; a < 3; ++a) m.positions.push_back(static_cast<float>(p[a]));
        }
        return static_cast<std::uint32_t>(v);
    };
    // Each face: axis a fixed at 0 or n-1, (b, c) the other two axes in right-handed order.
    for (int a = 0; a < 3; ++a) {
        const int b = (a + 1) % 3, c = (a + 2) % 3;
        for (int side = 0; side < 2; ++side) {
            for (int p = 0; p + 1 < n; ++p)
                for (int q = 0; q + 1 < n; ++q) {
                    std::array<std::uint32_t, 4> quad;
                    const std::array<std::array<int, 2>, 4> corners = {
                        std::array<int, 2>{p, q}, {p + 1, q}, {p + 1, q + 1}, {p, q + 1}};
                    for (std::size_t k = 0; k < 4; ++k) {
                        std::array<int, 3> ijk{};
                        ijk[static_cast<std::size_t>(a)] = side == 0 ? 0 : n - 1;
                        ijk[static_cast<std::size_t>(b)] = corners[k][0];
                        ijk[static_cast<std::size_t>(c)] = corners[k][1];
                        quad[k] = vertex(ijk[0], ijk[1], ijk[2]);
                    }
                    // b x c = a: counter-clockwise in (b, c) faces +a; flip on the low side.
                    if (side == 1) {
                        m.indices.insert(m.indices.end(), {quad[0], quad[1], quad[2]});
                        m.indices.insert(m.indices.end(), {quad[0], quad[2], quad[3]});
                    } else {
                        m.indices.insert(m.indices.end(), {quad[0], quad[2], quad[1]});
                        m.indices.insert(m.indices.end(), {quad[0], quad[3], quad[2]});
                    }
                }
        }
    }
    return m;
}

/// A smooth deformation of step @p s: a dent along +y under the centre, a twist about y and a
/// squash, scaled by @p amount (1: about a fifth of the size).
std::vector<float> deformed(const TriangleMesh& m, const Eigen::Vector3d& centre, double size,
                            double amount, int s) {
    std::vector<float> out(m.positions.size());
    const double phase = 0.7 * s;
    for (std::size_t v = 0; v < m.vertexCount(); ++v) {
        Eigen::Vector3d p(m.positions[3 * v], m.positions[3 * v + 1], m.positions[3 * v + 2]);
        Eigen::Vector3d q = (p - centre) / size;
        const double dent = 0.2 * amount * std::exp(-4 * (q.x() * q.x() + q.z() * q.z()));
        const double twist = 0.3 * amount * std::sin(phase) * q.y();
        const double c = std::cos(twist), sn = std::sin(twist);
        q = Eigen::Vector3d(c * q.x() - sn * q.z(), q.y() * (1 - 0.1 * amount * std::cos(phase)),
                            sn * q.x() + c * q.z());
        q.y() += dent * (q.y() < 0 ? 1 : 0.3);
        p = centre + size * q;
        for (int a = 0; a < 3; ++a)
            out[3 * v + static_cast<std::size_t>(a)] = static_cast<float>(p[a]);
    }
    return out;
}

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

/// Closest hit through raw Embree (every field of @p rh, as the reference scene reports it).
bool trace(RTCScene s, const Vec3f& o, const Vec3f& d, float tnear, float tfar, unsigned mask,
           RTCRayHit& rh) {
    RTCIntersectContext ctx;
    rtcInitIntersectContext(&ctx);
    rh.ray.org_x = o[0];
    rh.ray.org_y = o[1];
    rh.ray.org_z = o[2];
    rh.ray.dir_x = d[0];
    rh.ray.dir_y = d[1];
    rh.ray.dir_z = d[2];
    rh.ray.tnear = tnear;
    rh.ray.tfar = tfar;
    rh.ray.time = 0.0f;
    rh.ray.mask = mask;
    rh.ray.id = 0;
    rh.ray.flags = 0;
    rh.hit.geomID = RTC_INVALID_GEOMETRY_ID;
    rh.hit.instID[0] = RTC_INVALID_GEOMETRY_ID;
    rtcIntersect1(s, &ctx, &rh);
    return rh.hit.geomID != RTC_INVALID_GEOMETRY_ID;
}

/// Random rays from a shell around @p centre toward random points in a ball of radius
/// @p aim, some of them too short to reach the surface.
struct RandomRays {
    std::mt19937 rng;
    Eigen::Vector3d centre;
    double shell, aim;
    RandomRays(unsigned seed, const Eigen::Vector3d& c, double s, double a)
        : rng(seed), centre(c), shell(s), aim(a) {}
    void next(Vec3f& o, Vec3f& d, float& tfar) {
        std::normal_distribution<double> g;
        std::uniform_real_distribution<double> u(0, 1);
        const Eigen::Vector3d from =
            centre + shell * Eigen::Vector3d(g(rng), g(rng), g(rng)).normalized();
        const Eigen::Vector3d to =
            centre + aim * std::cbrt(u(rng)) * Eigen::Vector3d(g(rng), g(rng), g(rng)).normalized();
        const Eigen::Vector3d dir = (to - from).normalized();
        for (std::size_t a = 0; a < 3; ++a) {
            o[a] = static_cast<float>(from[static_cast<Eigen::Index>(a)]);
            d[a] = static_cast<float>(dir[static_cast<Eigen::Index>(a)]);
        }
        tfar = u(rng) < 0.1 ? static_cast<float>(0.5 * shell) : kInfF;
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

struct Shape {
    const char* name;
    TriangleMesh mesh;
    Eigen::Vector3d centre;
    double size;
};

std::vector<Shape> shapes() {
    const Eigen::Vector3d c(0.01, -0.02, 0.03);
    return {{"sphere", sphereMesh(c, 0.02, 48, 96), c, 0.02},
            {"box", boxSurface(5, 0.01, c - Eigen::Vector3d::Constant(0.02)), c, 0.02},
            {"hex13", boxSurface(13, 0.04 / 12, c - Eigen::Vector3d::Constant(0.02)), c, 0.02}};
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

// The user geometry under every way Embree hands it rays: single rays, 1M streams (coherent and
// not), packets of 4, 8 and 16 with partial valid masks, occlusion; masks and tnear honoured.
TEST(RefitMesh, EmbreeUserGeometryHandlesStreamsPacketsMasksAndOcclusion) {
    const Shape s = shapes()[0];
    RefitMesh mesh(s.mesh);
    EmbreeScene palp(/*robust=*/true);
    const unsigned geom = palp.addRefitMesh(mesh, kMaskSurface, 0.01f);
    palp.commit();
    ASSERT_EQ(mesh.refit(deformed(s.mesh, s.centre, s.size, 1.0, 2)), RefitStatus::Ok);
    // The twin geometry of the hit id gives the current triangle, as for an Embree mesh.
    const auto* v = static_cast<const float*>(
        rtcGetGeometryBufferData(rtcGetGeometry(palp.handle(), geom), RTC_BUFFER_TYPE_VERTEX, 0));
    ASSERT_EQ(v, mesh.positions().data());

    RandomRays rays(17, s.centre, 3 * s.size, 1.2 * s.size);
    constexpr int kN = 16;
    std::array<Vec3f, kN> org, dir;
    std::array<float, kN> tfar;
    std::array<TriangleHit, kN> want;
    std::array<bool, kN> wantHit;
    RTCIntersectContext ctx;
    int hits = 0;
    for (int round = 0; round < 40; ++round) {
        for (int i = 0; i < kN; ++i) {
            const auto k = static_cast<std::size_t>(i);
            rays.next(org[k], dir[k], tfar[k]);
            wantHit[k] = mesh.intersect(org[k], dir[k], 0.0f, tfar[k], want[k]);
            hits += wantHit[k] ? 1 : 0;
        }
        // 1M stream, both flags.
        for (const auto flag :
             {RTC_INTERSECT_CONTEXT_FLAG_INCOHERENT, RTC_INTERSECT_CONTEXT_FLAG_COHERENT}) {
            std::array<RTCRayHit, kN> rh{};
            for (std::size_t k = 0; k < kN; ++k) {
                rh[k].ray = {org[k][0], org[k][1], org[k][2], 0.0f,     dir[k][0], dir[k][1],
                             dir[k][2], 0.0f,      tfar[k],   kMaskAll, 0,         0};
                rh[k].hit.geomID = RTC_INVALID_GEOMETRY_ID;
            }
            rtcInitIntersectContext(&ctx);
            ctx.flags = flag;
            rtcIntersect1M(palp.handle(), &ctx, rh.data(), kN, sizeof(RTCRayHit));
            for (std::size_t k = 0; k < kN; ++k) {
                ASSERT_EQ(rh[k].hit.geomID != RTC_INVALID_GEOMETRY_ID, wantHit[k]);
                if (!wantHit[k]) continue;
                EXPECT_EQ(rh[k].hit.geomID, geom);
                EXPECT_EQ(rh[k].hit.primID, want[k].primId);
                EXPECT_EQ(rh[k].ray.tfar, want[k].t);
                EXPECT_EQ(rh[k].hit.v, want[k].v);
                EXPECT_EQ(rh[k].hit.Ng_z, want[k].ng[2]);
            }
        }
        // Packets: every other ray valid. Where the CPU has no native packet of a width (16
        // without AVX-512), Embree emulates it through its stream path, which ignores the valid
        // mask (rtcGetDeviceProperty NATIVE_RAY16_SUPPORTED): there the inactive rays are also
        // disabled the other documented way, tnear > tfar, so the test still checks the callback
        // against the rays Embree hands it.
        const RTCDevice device = rtcGetSceneDevice(palp.handle());
        const bool native16 =
            rtcGetDeviceProperty(device, RTC_DEVICE_PROPERTY_NATIVE_RAY16_SUPPORTED) != 0;
        rtcReleaseDevice(device);  // rtcGetSceneDevice retains it
        const auto packet = [&](auto& rh, auto intersect, int width) {
            alignas(64) std::array<int, kN> valid{};  // Embree loads it as a SIMD mask
            for (int i = 0; i < width; ++i) {
                const auto k = static_cast<std::size_t>(i);
                valid[k] = (i + round) % 2 == 0 ? -1 : 0;
                rh.ray.org_x[k] = org[k][0];
                rh.ray.org_y[k] = org[k][1];
                rh.ray.org_z[k] = org[k][2];
                rh.ray.dir_x[k] = dir[k][0];
                rh.ray.dir_y[k] = dir[k][1];
                rh.ray.dir_z[k] = dir[k][2];
                rh.ray.tnear[k] = 0.0f;
                if (width == 16 && !native16 && valid[k] == 0)
                    rh.ray.tnear[k] = std::numeric_limits<float>::infinity();
                rh.ray.tfar[k] = tfar[k];
                rh.ray.time[k] = 0.0f;
                rh.ray.mask[k] = kMaskSurface;
                rh.ray.id[k] = static_cast<unsigned>(i);
                rh.ray.flags[k] = 0;
                rh.hit.geomID[k] = RTC_INVALID_GEOMETRY_ID;
            }
            rtcInitIntersectContext(&ctx);
            intersect(valid.data(), palp.handle(), &ctx, &rh);
            for (int i = 0; i < width; ++i) {
                const auto k = static_cast<std::size_t>(i);
                const bool expect = valid[k] != 0 && wantHit[k];
                ASSERT_EQ(rh.hit.geomID[k] != RTC_INVALID_GEOMETRY_ID, expect)
                    << "width " << width << " lane " << i;
                if (!expect) continue;
                EXPECT_EQ(rh.hit.primID[k], want[k].primId);
                EXPECT_EQ(rh.ray.tfar[k], want[k].t);
                EXPECT_EQ(rh.hit.u[k], want[k].u);
            }
        };
        alignas(16) RTCRayHit4 p4;
        packet(p4, rtcIntersect4, 4);
        alignas(32) RTCRayHit8 p8;
        packet(p8, rtcIntersect8, 8);
        alignas(64) RTCRayHit16 p16;
        packet(p16, rtcIntersect16, 16);
        // Occlusion, a disjoint ray mask, and tnear beyond the hit.
        for (std::size_t k = 0; k < kN; ++k) {
            RTCRay r = {org[k][0], org[k][1], org[k][2], 0.0f,     dir[k][0], dir[k][1],
                        dir[k][2], 0.0f,      tfar[k],   kMaskAll, 0,         0};
            rtcInitIntersectContext(&ctx);
            rtcOccluded1(palp.handle(), &ctx, &r);
            EXPECT_EQ(r.tfar < 0, wantHit[k]);
            RTCRayHit rh;
            EXPECT_FALSE(trace(palp.handle(), org[k], dir[k], 0.0f, tfar[k], kMaskBone, rh));
            if (wantHit[k]) {
                ASSERT_TRUE(trace(palp.handle(), org[k], dir[k], 0.0f, tfar[k], kMaskSurface, rh));
                // Past the first hit, the next one (the far side) or nothing.
                const float t1 = want[k].t;
                if (trace(palp.handle(), org[k], dir[k], t1 * (1 + 1e-4f), tfar[k], kMaskAll, rh)) {
                    EXPECT_GT(rh.ray.tfar, t1);
                }
                EXPECT_FALSE(trace(palp.handle(), org[k], dir[k], 0.0f, 0.999f * t1, kMaskAll, rh));
            }
        }
    }
    // No error on the scene's device (rtcGetSceneDevice retains it).
    RTCDevice device = rtcGetSceneDevice(palp.handle());
    EXPECT_EQ(rtcGetDeviceError(device), RTC_ERROR_NONE);
    rtcReleaseDevice(device);
    EXPECT_GT(hits, 200);
}

// A refit that leaves the box registered with Embree is reported; inside it is not.
TEST(RefitMesh, ReportsLeavingTheRegisteredBox) {
    const Shape s = shapes()[1];
    RefitMesh mesh(s.mesh);
    EmbreeScene palp(true);
    palp.addRefitMesh(mesh, kMaskSurface, 0.005f);
    palp.commit();
    std::vector<float> p = s.mesh.positions;
    for (float& x : p) x += 0.004f;
    EXPECT_EQ(mesh.refit(p), RefitStatus::Ok);
    for (float& x : p) x += 0.002f;
    EXPECT_EQ(mesh.refit(p), RefitStatus::OutsideLimit);
    EXPECT_FLOAT_EQ(mesh.bounds().lo[0], s.mesh.positions[0] + 0.006f);
    EXPECT_THROW(palp.addRefitMesh(mesh, kMaskSurface, -1.0f), palp::ValueError);
    EXPECT_THROW(palp.addRefitMesh(mesh, kMaskSurface, kNan), palp::ValueError);
}

// Refit and queries allocate nothing (directly, through rtcIntersect1, 1M streams and
// rtcOccluded1 on the committed scene).
TEST(RefitMesh, ZeroAllocationsPerRefitAndQuery) {
    const Shape s = shapes()[2];
    RefitMesh mesh(s.mesh);
    EmbreeScene palp(true);
    palp.addRefitMesh(mesh, kMaskSurface, static_cast<float>(s.size));
    palp.commit();
    std::vector<std::vector<float>> frames;
    for (int i = 0; i < 4; ++i) frames.push_back(deformed(s.mesh, s.centre, s.size, 1.0, i));
    RandomRays rays(23, s.centre, 3 * s.size, s.size);
    std::vector<std::array<Vec3f, 2>> rs(256);
    for (auto& r : rs) {
        float tfar;
        rays.next(r[0], r[1], tfar);
    }
    std::array<RTCRayHit, 16> stream{};
    RTCIntersectContext ctx;
    rtcInitIntersectContext(&ctx);
    int hits = 0;
    const std::uint64_t before = palp::test::allocationCount();
    for (int tick = 0; tick < 200; ++tick) {
        if (mesh.refit(frames[static_cast<std::size_t>(tick) % frames.size()]) != RefitStatus::Ok)
            break;
        for (std::size_t i = 0; i < 16; ++i) {
            const auto& r = rs[(16 * static_cast<std::size_t>(tick) + i) % rs.size()];
            TriangleHit h;
            hits += mesh.intersect(r[0], r[1], 0.0f, kInfF, h) ? 1 : 0;
            hits += mesh.occluded(r[0], r[1], 0.0f, kInfF) ? 1 : 0;
            RTCRayHit rh;
            hits += trace(palp.handle(), r[0], r[1], 0.0f, kInfF, kMaskAll, rh) ? 1 : 0;
            RTCRay occ = {r[0][0], r[0][1], r[0][2], 0.0f,     r[1][0], r[1][1],
                          r[1][2], 0.0f,    kInfF,   kMaskAll, 0,       0};
            rtcOccluded1(palp.handle(), &ctx, &occ);
            stream[i].ray = occ;
            stream[i].ray.tfar = kInfF;
            stream[i].hit.geomID = RTC_INVALID_GEOMETRY_ID;
        }
        rtcIntersect1M(palp.handle(), &ctx, stream.data(), 16, sizeof(RTCRayHit));
    }
    EXPECT_EQ(palp::test::allocationCount() - before, 0u);
    EXPECT_GT(hits, 200 * 16);
    // Slack refits (their scratch is reserved by setRefitSlack) allocate nothing either.
    mesh.setRefitSlack(static_cast<float>(0.01 * s.size));
    const std::uint64_t beforeSlack = palp::test::allocationCount();
    for (int tick = 0; tick < 200; ++tick)
        ASSERT_EQ(mesh.refit(frames[static_cast<std::size_t>(tick) % frames.size()]),
                  RefitStatus::Ok);
    EXPECT_EQ(palp::test::allocationCount() - beforeSlack, 0u);
}

// NaN or infinite rays, a zero direction, tnear > tfar and degenerate triangles give no hit
// (and return); bad meshes and bad refits are refused.
TEST(RefitMesh, DegenerateInputGivesNoHit) {
    TriangleMesh m = boxSurface(3, 0.01, Eigen::Vector3d::Zero());
    const auto boxTriangles = static_cast<std::uint32_t>(m.triangleCount());
    // Degenerate triangles inside the box's face plane z = 0 and in the open: a point and a
    // segment.
    const auto base = static_cast<std::uint32_t>(m.vertexCount());
    for (float x : {0.005f, 0.005f, 0.005f, 0.001f, 0.002f, 0.003f})
        m.positions.insert(m.positions.end(), {x, 0.03f, 0.005f});
    m.indices.insert(m.indices.end(), {base, base + 1, base + 2, base + 3, base + 4, base + 5});
    RefitMesh mesh(m);
    const Vec3f o = {0.005f, 0.05f, 0.005f};
    TriangleHit h;
    // Straight at the degenerate triangles: they are skipped, the box top (y = 0.02) is hit.
    ASSERT_TRUE(mesh.intersect(o, {0, -1, 0}, 0.0f, kInfF, h));
    EXPECT_FLOAT_EQ(h.t, 0.03f);
    EXPECT_LT(h.primId, boxTriangles);
    EXPECT_FALSE(mesh.intersect(o, {0, -1, 0}, 0.0f, 0.025f, h));  // only the segment before
    for (const Vec3f& d : std::array<Vec3f, 4>{Vec3f{0, 0, 0}, Vec3f{kNan, -1, 0},
                                               Vec3f{0, -kInfF, 0}, Vec3f{0, -1e-45f, 0}}) {
        // A denormal direction may overflow 1 / d: no hit then, but an answer.
        const bool hit = mesh.intersect(o, d, 0.0f, kInfF, h);
        if (d[1] != -1e-45f) {
            EXPECT_FALSE(hit);
        }
        EXPECT_EQ(mesh.occluded(o, d, 0.0f, kInfF), hit);
    }
    EXPECT_FALSE(mesh.intersect({kNan, 0, 0}, {0, -1, 0}, 0.0f, kInfF, h));
    EXPECT_FALSE(mesh.intersect(o, {0, -1, 0}, kNan, kInfF, h));
    EXPECT_FALSE(mesh.intersect(o, {0, -1, 0}, 0.0f, kNan, h));
    EXPECT_FALSE(mesh.intersect(o, {0, -1, 0}, 1.0f, 0.5f, h));
    // A mesh of degenerate triangles only is never hit.
    TriangleMesh flat;
    flat.positions = {0, 0, 0, 1, 1, 1, 2, 2, 2, 0, 0, 0};
    flat.indices = {0, 1, 2, 0, 3, 0, 1, 1, 1};
    RefitMesh line(flat);
    std::mt19937 rng(1);
    std::uniform_real_distribution<float> u(-1, 1);
    for (int i = 0; i < 1000; ++i) {
        const float s = u(rng) + 1;
        EXPECT_FALSE(line.intersect({s + u(rng), s + u(rng), s - 1}, {0, 0, 1}, 0.0f, kInfF, h));
        EXPECT_FALSE(line.intersect({-1, -1, -1}, {1, 1, 1}, 0.0f, kInfF, h));
    }
    // Refits with a wrong size or a non-finite coordinate change nothing.
    const Box3f before = mesh.bounds();
    std::vector<float> p = m.positions;
    p[4] = kNan;
    EXPECT_EQ(mesh.refit(p), RefitStatus::Rejected);
    p.pop_back();
    EXPECT_EQ(mesh.refit(p), RefitStatus::Rejected);
    EXPECT_EQ(mesh.bounds().lo, before.lo);
    EXPECT_EQ(mesh.bounds().hi, before.hi);
    // Bad meshes.
    TriangleMesh bad = m;
    bad.indices[7] = 1000;
    EXPECT_THROW(RefitMesh{bad}, palp::ValueError);
    bad = m;
    bad.positions[2] = kInfF;
    EXPECT_THROW(RefitMesh{bad}, palp::ValueError);
    EXPECT_THROW(RefitMesh{TriangleMesh{}}, palp::ValueError);
    EXPECT_THROW(RefitMesh(m, 0), palp::ValueError);
}

// The tree's depth stays near log2(#T / leafSize) (binned SAH, median splits when the centroids
// coincide), within the fixed traversal stack; every triangle is reachable.
TEST(RefitMesh, TreeDepthIsBounded) {
    for (const Shape& s : shapes()) {
        for (int leaf : {1, 4, 16}) {
            RefitMesh mesh(s.mesh, leaf);
            const double log2n = std::log2(static_cast<double>(s.mesh.triangleCount()) / leaf);
            EXPECT_LE(mesh.depth(), static_cast<int>(2 * std::ceil(log2n)) + 1)
                << s.name << " leaf " << leaf;
            EXPECT_LE(mesh.nodeCount(), 2 * s.mesh.triangleCount());
        }
    }
    // 1,000 copies of one triangle: no centroid spread, so median splits: a balanced tree; a ray
    // through it hits one of them (all tie).
    TriangleMesh same;
    same.positions = {0, 0, 0, 1, 0, 0, 0, 1, 0};
    for (int i = 0; i < 1000; ++i) same.indices.insert(same.indices.end(), {0, 1, 2});
    RefitMesh mesh(same, 2);
    EXPECT_LE(mesh.depth(), 10);
    TriangleHit h;
    ASSERT_TRUE(mesh.intersect({0.25f, 0.25f, 1}, {0, 0, -1}, 0.0f, kInfF, h));
    EXPECT_EQ(h.t, 1.0f);
    EXPECT_LT(h.primId, 1000u);
}

}  // namespace
