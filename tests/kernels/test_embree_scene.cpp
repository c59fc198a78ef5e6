#include <gtest/gtest.h>
#include <tbb/task_arena.h>

#include <cmath>
#include <fstream>
#include <random>
#include <vector>

#include "alloc_counter.h"
#include "mesh_test_shapes.h"
#include "palp/base/error.h"
#include "palp/kernels/embree_scene.h"
#include "palp/kernels/ray_batch.h"
#include "palp/kernels/triangle_mesh.h"
#include "palp/volume/mesh.h"
#include "ray_test_shapes.h"
#include "test_support.h"

namespace {

using namespace palp::kernels;
using palp::test::boxMesh;
using palp::test::bundleAt;
using palp::test::icosphere;
using palp::test::kVoxel;
using palp::test::planeMesh;

/// Exact closest hit against a mesh in double precision (brute force, Moller-Trumbore on the
/// float vertices).
double bruteForceHit(const TriangleMesh& m, const Eigen::Vector3d& o, const Eigen::Vector3d& d,
                     double tMax) {
    double best = std::numeric_limits<double>::infinity();
    auto vert = [&](std::uint32_t i) {
        return Eigen::Vector3d(m.positions[3 * i], m.positions[3 * i + 1], m.positions[3 * i + 2]);
    };
    for (std::size_t t = 0; t < m.triangleCount(); ++t) {
        const Eigen::Vector3d a = vert(m.indices[3 * t]), b = vert(m.indices[3 * t + 1]),
                              c = vert(m.indices[3 * t + 2]);
        const Eigen::Vector3d e1 = b - a, e2 = c - a, p = d.cross(e2);
        const double det = e1.dot(p);
        if (std::fabs(det) < 1e-300) continue;
        const Eigen::Vector3d s = o - a;
        const double u = s.dot(p) / det;
        if (u < 0 || u > 1) continue;
        const Eigen::Vector3d q = s.cross(e1);
        const double w = d.dot(q) / det;
        if (w < 0 || u + w > 1) continue;
        const double tt = e2.dot(q) / det;
        if (tt >= 0 && tt <= tMax) best = std::min(best, tt);
    }
    return best;
}

// Rays whose origin lies inside the solid (inside(o)) are left out: the exact functions give the
// entry into the solid from outside.
template <class Exact, class Inside>
void checkMeshAgainst(const TriangleMesh& mesh, Exact exact, Inside inside,
                      const Eigen::Vector3d& c, double r0, double aim) {
    EmbreeScene scene;
    scene.addRigidMesh(mesh, kMaskBone);
    scene.commit();
    std::mt19937 rng(11);
    std::normal_distribution<double> n;
    int hits = 0;
    for (int k = 0; k < 60; ++k) {
        const Eigen::Vector3d proxy = c + r0 * Eigen::Vector3d(n(rng), n(rng), n(rng)).normalized();
        const Eigen::Vector3d target =
            c + aim * Eigen::Vector3d(n(rng), n(rng), n(rng)).normalized();
        const RayBundle b = bundleAt(proxy, target, 8, 2 * r0);
        for (MeshTraceMode mode : {MeshTraceMode::Loop1, MeshTraceMode::Stream1M}) {
            BundleHits h;
            traceBundle(scene, b, kMaskAll, h, mode);
            ASSERT_EQ(h.count, 25);
            for (int r = 0; r < h.count; ++r) {
                const auto i = static_cast<std::size_t>(r);
                const Eigen::Vector3d o(b.ox[i], b.oy[i], b.oz[i]), d(b.dx[i], b.dy[i], b.dz[i]);
                if (inside(o)) continue;
                const double e = exact(o, d);
                if (!(e <= 2 * r0)) {
                    EXPECT_FALSE(h.hit[i]);
                    continue;
                }
                ASSERT_TRUE(h.hit[i]) << "bundle " << k << " ray " << r;
                EXPECT_NEAR(h.t[i], e, 1e-6);
                ++hits;
            }
        }
    }
    EXPECT_GT(hits, 500);
}

TEST(EmbreeScene, PlaneBoxAndSphereHitsWithinAMicrometre) {
    const palp::test::Plane plane{Eigen::Vector3d(0.2, -0.3, 1.0).normalized(), 0.7e-3};
    checkMeshAgainst(
        planeMesh(plane.n, plane.c * plane.n, 0.1),
        [&](const Eigen::Vector3d& o, const Eigen::Vector3d& d) { return plane.hit(o, d); },
        [&](const Eigen::Vector3d& o) { return plane.sdf(o) <= 0; }, Eigen::Vector3d::Zero(), 8e-3,
        4e-3);
    const palp::test::Box box{Eigen::Vector3d(0.1e-3, 0.2e-3, -0.3e-3),
                              Eigen::Vector3d(5e-3, 4e-3, 3.5e-3)};
    checkMeshAgainst(
        boxMesh(box),
        [&](const Eigen::Vector3d& o, const Eigen::Vector3d& d) { return box.hit(o, d); },
        [&](const Eigen::Vector3d& o) { return box.sdf(o) <= 0; }, box.centre, 10e-3, 3e-3);
    const palp::test::Sphere s{Eigen::Vector3d(0.13e-3, -0.21e-3, 0.07e-3), 6e-3};
    const TriangleMesh ico = icosphere(s, 3);
    checkMeshAgainst(
        ico,
        [&](const Eigen::Vector3d& o, const Eigen::Vector3d& d) {
            return bruteForceHit(ico, o, d, 1.0);
        },
        [&](const Eigen::Vector3d& o) { return s.sdf(o) <= 0; }, s.centre, 9.5e-3, 4e-3);
}

// The same shape as a volume and as a mesh (analytic and iso-surface) agrees within half a voxel.
TEST(EmbreeScene, VolumeAndMeshAgreeWithinHalfAVoxel) {
    const palp::test::Sphere s{Eigen::Vector3d(0.13e-3, -0.21e-3, 0.07e-3), 6e-3};
    auto grid = palp::test::shapeVolume([&](const Eigen::Vector3d& x) { return s.sdf(x); },
                                        {-20, -20, -20}, {20, 20, 20});
    const VolumeView view(grid);
    EmbreeScene analytic, iso;
    analytic.addRigidMesh(icosphere(s, 5));
    analytic.commit();
    const TriangleMesh isoMesh = palp::volume::isoSurface(*grid, palp::test::kIso);
    ASSERT_GT(isoMesh.triangleCount(), 1000u);
    iso.addRigidMesh(isoMesh);
    iso.commit();
    FirstHitParams fp;
    fp.threshold = palp::test::kIso;
    std::mt19937 rng(13);
    std::normal_distribution<double> n;
    int compared = 0;
    for (int k = 0; k < 40; ++k) {
        const Eigen::Vector3d proxy =
            s.centre + 9.5e-3 * Eigen::Vector3d(n(rng), n(rng), n(rng)).normalized();
        const RayBundle b = bundleAt(proxy, s.centre, 8);
        BundleHits hv, ha, hi;
        traceFirstHit(view, b, fp, hv);
        traceBundle(analytic, b, kMaskAll, ha);
        traceBundle(iso, b, kMaskAll, hi);
        for (int r = 0; r < b.count; ++r) {
            const auto i = static_cast<std::size_t>(r);
            ASSERT_TRUE(hv.hit[i] && ha.hit[i] && hi.hit[i]);
            EXPECT_NEAR(hv.t[i], ha.t[i], 0.5 * kVoxel);
            EXPECT_NEAR(hv.t[i], hi.t[i], 0.5 * kVoxel);
            ++compared;
        }
    }
    EXPECT_EQ(compared, 40 * 25);
}

TEST(EmbreeScene, MasksSelectCategoriesAndRefitMovesADeformingMesh) {
    EmbreeScene scene;
    const unsigned bone = scene.addRigidMesh(
        planeMesh(Eigen::Vector3d::UnitZ(), Eigen::Vector3d(0, 0, -6e-3), 0.05), kMaskBone);
    const unsigned plate = scene.addRigidMesh(
        planeMesh(Eigen::Vector3d::UnitZ(), Eigen::Vector3d(0, 0, -4e-3), 0.05), kMaskPlate);
    TriangleMesh skin = planeMesh(Eigen::Vector3d::UnitZ(), Eigen::Vector3d(0, 0, -2e-3), 0.05);
    const unsigned surf = scene.addDeformingMesh(skin, kMaskSurface);
    scene.commit();
    EXPECT_EQ(scene.triangleCount(), 6u);
    const RayBundle b = bundleAt(Eigen::Vector3d(0, 0, 0), Eigen::Vector3d(0, 0, -1));
    BundleHits h;
    traceBundle(scene, b, kMaskBone, h);
    EXPECT_NEAR(h.t[0], 6e-3, 1e-7);
    EXPECT_EQ(h.geomId[0], bone);
    traceBundle(scene, b, kMaskBone | kMaskPlate, h);
    EXPECT_NEAR(h.t[0], 4e-3, 1e-7);
    EXPECT_EQ(h.geomId[0], plate);
    traceBundle(scene, b, kMaskAll, h);
    EXPECT_NEAR(h.t[0], 2e-3, 1e-7);
    EXPECT_EQ(h.geomId[0], surf);
    // Push the skin down to -3 mm and refit.
    for (std::size_t v = 0; v < skin.vertexCount(); ++v) skin.positions[3 * v + 2] = -3e-3f;
    EXPECT_TRUE(scene.updateVertices(surf, skin.positions));
    EXPECT_FALSE(scene.updateVertices(bone, skin.positions));  // rigid
    EXPECT_FALSE(scene.updateVertices(surf, std::span<const float>(skin.positions).first(3)));
    scene.commit();
    traceBundle(scene, b, kMaskSurface, h);
    EXPECT_NEAR(h.t[0], 3e-3, 1e-7);
    // Nothing in the mask: no hit, t is the ray length.
    traceBundle(scene, b, 8u, h);
    EXPECT_FALSE(h.hit[0]);
    EXPECT_FLOAT_EQ(h.t[0], b.length[0]);
}

TEST(EmbreeScene, DegenerateInputAndNoAllocation) {
    EmbreeScene empty;
    const RayBundle b = bundleAt(Eigen::Vector3d(0, 0, 0), Eigen::Vector3d(0, 0, -1));
    BundleHits h;
    traceBundle(empty, b, kMaskAll, h);  // not committed, empty
    EXPECT_EQ(h.count, 17);
    EXPECT_FALSE(h.hit[0]);
    empty.commit();
    traceBundle(empty, b, kMaskAll, h, MeshTraceMode::Stream1M);
    EXPECT_FALSE(h.hit[0]);
    EXPECT_THROW(empty.addRigidMesh(TriangleMesh{}), palp::ValueError);
    TriangleMesh bad = planeMesh(Eigen::Vector3d::UnitZ(), Eigen::Vector3d::Zero(), 1);
    bad.indices[2] = 99;
    EXPECT_THROW(empty.addRigidMesh(bad), palp::ValueError);

    EmbreeScene scene;
    scene.addRigidMesh(planeMesh(Eigen::Vector3d::UnitZ(), Eigen::Vector3d(0, 0, -5e-3), 0.05));
    scene.commit();
    RayBundle invalid;
    generateBundle(Eigen::Vector3d::Zero(), Eigen::Vector3d(std::nan(""), 0, 0),
                   Eigen::Vector3d::UnitX(), Eigen::Vector3d::UnitY(), BundleParams{}, invalid);
    traceBundle(scene, invalid, kMaskAll, h);
    EXPECT_EQ(h.count, 0);
    // Zero length: no hit.
    BundleParams zp;
    zp.length = 0;
    RayBundle z;
    generateBundle(Eigen::Vector3d::Zero(), Eigen::Vector3d(0, 0, -1), Eigen::Vector3d::UnitX(),
                   Eigen::Vector3d::UnitY(), zp, z);
    traceBundle(scene, z, kMaskAll, h);
    EXPECT_FALSE(h.hit[0]);
    // Huge length: a hit.
    zp.length = 1e30;
    generateBundle(Eigen::Vector3d::Zero(), Eigen::Vector3d(0, 0, -1), Eigen::Vector3d::UnitX(),
                   Eigen::Vector3d::UnitY(), zp, z);
    traceBundle(scene, z, kMaskAll, h);
    EXPECT_NEAR(h.t[0], 5e-3, 1e-7);
    // No allocation per frame.
    int hits = 0;
    const std::uint64_t before = palp::test::allocationCount();
    for (int frame = 0; frame < 200; ++frame) {
        const RayBundle fb =
            bundleAt(Eigen::Vector3d(frame * 1e-5, 0, 0), Eigen::Vector3d(frame * 1e-5, 0, -1), 8);
        traceBundle(scene, fb, kMaskAll, h, MeshTraceMode::Loop1);
        hits += h.hit[0];
        traceBundle(scene, fb, kMaskAll, h, MeshTraceMode::Stream1M);
        hits += h.hit[0];
    }
    EXPECT_EQ(palp::test::allocationCount() - before, 0u);
    EXPECT_EQ(hits, 400);
}

}  // namespace
