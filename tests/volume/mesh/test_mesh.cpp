#include <gtest/gtest.h>

#include <Eigen/Core>
#include <cstdint>
#include <fstream>

#include "palp/base/error.h"
#include "palp/volume/mesh.h"
#include "test_support.h"

namespace {

using palp::TriangleMesh;
using palp::volume::loadMesh;
using palp::volume::saveObj;

/// The 12 triangles of the box with centre @p c and half-sizes @p half.
TriangleMesh boxMesh(const Eigen::Vector3d& c, const Eigen::Vector3d& half) {
    TriangleMesh m;
    for (int k = 0; k < 8; ++k) {
        const Eigen::Vector3d p =
            c + Eigen::Vector3d((k & 1) ? half.x() : -half.x(), (k & 2) ? half.y() : -half.y(),
                                (k & 4) ? half.z() : -half.z());
        for (int a = 0; a < 3; ++a) m.positions.push_back(static_cast<float>(p[a]));
    }
    const std::uint32_t f[6][4] = {{0, 2, 6, 4}, {1, 5, 7, 3}, {0, 4, 5, 1},
                                   {2, 3, 7, 6}, {0, 1, 3, 2}, {4, 6, 7, 5}};
    for (const auto& q : f) m.indices.insert(m.indices.end(), {q[0], q[1], q[2], q[0], q[2], q[3]});
    return m;
}

TEST(MeshIo, ObjStlPlyRoundTrip) {
    palp::test::TempDir dir;
    const TriangleMesh box = boxMesh(Eigen::Vector3d(1, 2, 3), Eigen::Vector3d(0.5, 0.25, 1));
    saveObj(box, dir / "box.obj");
    {
        std::ofstream stl(dir / "box.stl");
        stl << "solid box\n";
        for (std::size_t t = 0; t < box.triangleCount(); ++t) {
            stl << "facet normal 0 0 0\nouter loop\n";
            for (int k = 0; k < 3; ++k) {
                const std::uint32_t v = box.indices[3 * t + static_cast<std::size_t>(k)];
                stl << "vertex " << box.positions[3 * v] << ' ' << box.positions[3 * v + 1] << ' '
                    << box.positions[3 * v + 2] << '\n';
            }
            stl << "endloop\nendfacet\n";
        }
        stl << "endsolid box\n";
        std::ofstream ply(dir / "box.ply");
        ply << "ply\nformat ascii 1.0\nelement vertex " << box.vertexCount()
            << "\nproperty float x\nproperty float y\nproperty float z\nelement face "
            << box.triangleCount() << "\nproperty list uchar int vertex_indices\nend_header\n";
        for (std::size_t v = 0; v < box.vertexCount(); ++v)
            ply << box.positions[3 * v] << ' ' << box.positions[3 * v + 1] << ' '
                << box.positions[3 * v + 2] << '\n';
        for (std::size_t t = 0; t < box.triangleCount(); ++t)
            ply << "3 " << box.indices[3 * t] << ' ' << box.indices[3 * t + 1] << ' '
                << box.indices[3 * t + 2] << '\n';
    }
    for (const char* name : {"box.obj", "box.stl", "box.ply"}) {
        const TriangleMesh m = loadMesh(dir / name, 1e-3);  // millimetres
        EXPECT_EQ(m.triangleCount(), 12u) << name;
        // Every loaded vertex is a box corner scaled to metres.
        for (std::size_t v = 0; v < m.vertexCount(); ++v) {
            const Eigen::Vector3d p(m.positions[3 * v], m.positions[3 * v + 1],
                                    m.positions[3 * v + 2]);
            const Eigen::Vector3d q = (p * 1e3 - Eigen::Vector3d(1, 2, 3)).cwiseAbs();
            EXPECT_NEAR(q.x(), 0.5, 1e-5) << name;
            EXPECT_NEAR(q.y(), 0.25, 1e-5) << name;
            EXPECT_NEAR(q.z(), 1.0, 1e-5) << name;
        }
    }
    EXPECT_THROW(loadMesh(dir / "missing.stl"), palp::IoError);
    {
        std::ofstream junk(dir / "junk.ply");
        junk << "not a mesh";
    }
    EXPECT_THROW(loadMesh(dir / "junk.ply"), palp::FormatError);
}

}  // namespace
