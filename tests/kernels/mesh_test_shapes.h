#pragma once
// Triangle meshes of the analytic shapes (a square, a box, an icosphere) and a ray bundle aimed
// at a point, shared by the mesh ray tests (test_embree_scene.cpp, test_ray_batch.cpp).
#include <Eigen/Core>
#include <array>
#include <cmath>
#include <cstdint>
#include <vector>

#include "palp/kernels/ray_bundle.h"
#include "palp/kernels/triangle_mesh.h"
#include "ray_test_shapes.h"

namespace palp::test {

using palp::kernels::BundleParams;
using palp::kernels::RayBundle;
using palp::kernels::TriangleMesh;

inline void addVertex(TriangleMesh& m, const Eigen::Vector3d& p) {
    for (int a = 0; a < 3; ++a) m.positions.push_back(static_cast<float>(p[a]));
}
inline void addTri(TriangleMesh& m, std::uint32_t a, std::uint32_t b, std::uint32_t c) {
    m.indices.insert(m.indices.end(), {a, b, c});
}

/// Square of half-size @p s in the plane through @p c with normal @p n.
inline TriangleMesh planeMesh(const Eigen::Vector3d& n, const Eigen::Vector3d& c, double s) {
    Eigen::Vector3d u, v;
    palp::kernels::orthonormalBasis(n, u, v);
    TriangleMesh m;
    addVertex(m, c - s * u - s * v);
    addVertex(m, c + s * u - s * v);
    addVertex(m, c + s * u + s * v);
    addVertex(m, c - s * u + s * v);
    addTri(m, 0, 1, 2);
    addTri(m, 0, 2, 3);
    return m;
}

inline TriangleMesh boxMesh(const palp::test::Box& b) {
    TriangleMesh m;
    for (int k = 0; k < 8; ++k)
        addVertex(m, b.centre + Eigen::Vector3d((k & 1) ? b.half.x() : -b.half.x(),
                                                (k & 2) ? b.half.y() : -b.half.y(),
                                                (k & 4) ? b.half.z() : -b.half.z()));
    const std::uint32_t f[6][4] = {{0, 2, 6, 4}, {1, 5, 7, 3}, {0, 4, 5, 1},
                                   {2, 3, 7, 6}, {0, 1, 3, 2}, {4, 6, 7, 5}};
    for (const auto& q : f) {
        addTri(m, q[0], q[1], q[2]);
        addTri(m, q[0], q[2], q[3]);
    }
    return m;
}

/// Icosphere: icosahedron subdivided @p levels times, vertices on the sphere.
inline TriangleMesh icosphere(const palp::test::Sphere& s, int levels) {
    const double t = (1 + std::sqrt(5.0)) / 2;
    std::vector<Eigen::Vector3d> v = {{-1, t, 0}, {1, t, 0}, {-1, -t, 0}, {1, -t, 0},
                                      {0, -1, t}, {0, 1, t}, {0, -1, -t}, {0, 1, -t},
                                      {t, 0, -1}, {t, 0, 1}, {-t, 0, -1}, {-t, 0, 1}};
    std::vector<std::array<std::uint32_t, 3>> f = {
        {0, 11, 5},  {0, 5, 1},  {0, 1, 7},  {0, 7, 10}, {0, 10, 11}, {1, 5, 9}, {5, 11, 4},
        {11, 10, 2}, {10, 7, 6}, {7, 1, 8},  {3, 9, 4},  {3, 4, 2},   {3, 2, 6}, {3, 6, 8},
        {3, 8, 9},   {4, 9, 5},  {2, 4, 11}, {6, 2, 10}, {8, 6, 7},   {9, 8, 1}};
    for (auto& p : v) p.normalize();
    for (int l = 0; l < levels; ++l) {
        std::vector<std::array<std::uint32_t, 3>> nf;
        for (const auto& tri : f) {
            std::uint32_t m[3];
            for (int e = 0; e < 3; ++e) {
                v.push_back((v[tri[static_cast<std::size_t>(e)]] +
                             v[tri[static_cast<std::size_t>((e + 1) % 3)]])
                                .normalized());
                m[e] = static_cast<std::uint32_t>(v.size() - 1);
            }
            nf.push_back({tri[0], m[0], m[2]});
            nf.push_back({tri[1], m[1], m[0]});
            nf.push_back({tri[2], m[2], m[1]});
            nf.push_back({m[0], m[1], m[2]});
        }
        f = nf;
    }
    TriangleMesh out;
    for (const auto& p : v) addVertex(out, s.centre + s.radius * p);
    for (const auto& tri : f) addTri(out, tri[0], tri[1], tri[2]);
    return out;
}

/// One bundle per proxy pointing at @p target, for tests.
inline RayBundle bundleAt(const Eigen::Vector3d& proxy, const Eigen::Vector3d& target, int ring = 0,
                          double len = 20e-3) {
    BundleParams p;
    p.length = len;
    p.ringCount = ring;
    p.sobelAngle = 0.08;
    p.surfaceOffset = 0.8e-3;
    RayBundle b;
    palp::kernels::generateBundle(proxy, target - proxy, Eigen::Vector3d(1, 0, 0),
                                  Eigen::Vector3d(0, 1, 0), p, b);
    return b;
}

}  // namespace palp::test
