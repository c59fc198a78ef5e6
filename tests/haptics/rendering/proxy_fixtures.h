#pragma once
// Shared by the proxy tests (test_proxy*.cpp): the spring and servo period they drive the proxy
// with, and the simple meshes they touch (a plane quad, a closed box, a scene of the plane).
#include <Eigen/Core>
#include <cstdint>

#include "palp/haptics/rendering/proxy.h"
#include "palp/kernels/embree_scene.h"
#include "ray_test_shapes.h"

namespace palp::haptics::pfix {

using Eigen::Vector3d;
using palp::haptics::Proxy;
using palp::haptics::ProxyParams;
using palp::haptics::ProxyState;
using palp::kernels::EmbreeScene;
using palp::kernels::intersectOne;
using palp::kernels::kMaskSurface;
using palp::kernels::MeshHit;
using palp::kernels::TriangleMesh;

inline constexpr double kK = 1000.0;  // N/m
inline constexpr double kDt = 1e-3;   // s
inline const Vector3d kNoForce = Vector3d::Zero();

inline void addVertex(TriangleMesh& m, const Vector3d& p) {
    for (int a = 0; a < 3; ++a) m.positions.push_back(static_cast<float>(p[a]));
}

/// The plane z = 0 as a square quad of half-width @p half (two triangles).
inline TriangleMesh planeQuad(double half) {
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
inline TriangleMesh boxMesh(const palp::test::Box& box) {
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

}  // namespace palp::haptics::pfix
