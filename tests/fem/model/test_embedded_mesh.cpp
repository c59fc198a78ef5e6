// EmbeddedMesh: vertices tied to hex cells by trilinear weights follow the lattice's
// displacement field (exact for affine fields, consistent across shared faces, edges and
// nodes), clamped vertices move with the nearest point of their cell, update() allocates
// nothing, and bad meshes are refused by name.

#include <gtest/gtest.h>

#include <Eigen/Core>
#include <cmath>
#include <limits>
#include <random>
#include <vector>

#include "alloc_counter.h"
#include "palp/base/error.h"
#include "palp/fem/embedded_mesh.h"
#include "palp/fem/voxelize.h"
#include "palp/volume/phantom.h"
#include "test_support.h"

namespace palp::fem {
namespace {

using palp::test::expectThrowWith;

TriangleMesh pointsMesh(const std::vector<Eigen::Vector3d>& points) {
    TriangleMesh m;
    for (const Eigen::Vector3d& p : points) {
        for (int a = 0; a < 3; ++a) m.positions.push_back(static_cast<float>(p[a]));
    }
    // Triangles over consecutive vertices (the topology is carried, not used).
    for (std::uint32_t v = 0; v + 2 < points.size(); v += 3) {
        m.indices.insert(m.indices.end(), {v, v + 1, v + 2});
    }
    return m;
}

Eigen::Vector3d vertex(const TriangleMesh& m, std::size_t v) {
    return {m.positions[3 * v], m.positions[3 * v + 1], m.positions[3 * v + 2]};
}

// u_n = A X_n + b on every node (active or not).
Eigen::VectorXd affineField(const HexMesh& mesh, const Eigen::Matrix3d& a,
                            const Eigen::Vector3d& b) {
    Eigen::VectorXd u(mesh.dofCount());
    for (int n = 0; n < mesh.nodeCount(); ++n) u.segment<3>(3 * n) = a * mesh.nodePosition(n) + b;
    return u;
}

const Eigen::Matrix3d kA = (Eigen::Matrix3d() << 0.03, -0.11, 0.07,  //
                            0.05, 0.02, -0.09,                       //
                            -0.04, 0.08, 0.01)
                               .finished();
const Eigen::Vector3d kB(1.5e-3, -2.5e-3, 0.7e-3);

TEST(EmbeddedMesh, AffineDisplacementIsReproducedExactly) {
    // A 5 mm lattice at an awkward origin (cell edges not binary fractions).
    const Eigen::Vector3d origin(-0.0213, 0.0017, -0.0309);
    const HexMesh mesh = HexMesh::box(Eigen::Vector3d(0.020, 0.015, 0.025), {5, 4, 6}, 1.0, origin);
    std::mt19937 rng(7);
    std::uniform_real_distribution<double> unit(0.0, 1.0);
    std::vector<Eigen::Vector3d> points;
    for (int i = 0; i < 300; ++i) {
        points.push_back(origin +
                         Eigen::Vector3d(0.020 * unit(rng), 0.015 * unit(rng), 0.025 * unit(rng)));
    }
    for (int n : {mesh.node(1, 1, 1), mesh.node(2, 1, 3), mesh.node(3, 2, 4)})
        points.push_back(mesh.nodePosition(n));
    const TriangleMesh rest = pointsMesh(points);
    const EmbeddedMesh em(mesh, rest);
    ASSERT_EQ(em.vertexCount(), points.size());
    EXPECT_EQ(em.dofCount(), mesh.dofCount());

    const Eigen::VectorXd u = affineField(mesh, kA, kB);
    std::vector<double> x(3 * em.vertexCount());
    ASSERT_TRUE(em.update(u, std::span<double>(x)));
    double worst = 0;
    for (std::size_t v = 0; v < em.vertexCount(); ++v) {
        const Eigen::Vector3d rv = vertex(rest, v);
        const Eigen::Vector3d expected = rv + kA * rv + kB;
        const Eigen::Vector3d got(x[3 * v], x[3 * v + 1], x[3 * v + 2]);
        worst = std::max(worst, (got - expected).cwiseAbs().maxCoeff());
        double sum = 0;
        for (double w : em.weights(v)) sum += w;
        EXPECT_NEAR(sum, 1.0, 1e-15);
    }
    EXPECT_LT(worst, 1e-12) << "largest deviation from A X + b, m";
    // Float output: the same to float rounding of positions of a few centimetres.
    std::vector<float> xf(3 * em.vertexCount());
    ASSERT_TRUE(em.update(u, std::span<float>(xf)));
    for (std::size_t i = 0; i < xf.size(); ++i) EXPECT_NEAR(xf[i], x[i], 1e-8);
    // All vertices lie inside the box: nothing clamped.
    EXPECT_EQ(em.clampedCount(), 0);
    EXPECT_EQ(em.maxClampDistance(), 0.0);
}

TEST(EmbeddedMesh, RigidTranslationMovesTheMeshRigidly) {
    const HexMesh mesh = HexMesh::box(Eigen::Vector3d(0.03, 0.03, 0.03), {4, 4, 4});
    std::mt19937 rng(11);
    std::uniform_real_distribution<double> coord(0.0, 0.03);
    std::vector<Eigen::Vector3d> points;
    for (int i = 0; i < 99; ++i) points.emplace_back(coord(rng), coord(rng), coord(rng));
    const TriangleMesh rest = pointsMesh(points);
    const EmbeddedMesh em(mesh, rest);
    const Eigen::Vector3d t(0.004, -0.0025, 0.001);
    Eigen::VectorXd u(mesh.dofCount());
    for (int n = 0; n < mesh.nodeCount(); ++n) u.segment<3>(3 * n) = t;
    std::vector<double> x(3 * em.vertexCount());
    ASSERT_TRUE(em.update(u, std::span<double>(x)));
    for (std::size_t v = 0; v < em.vertexCount(); ++v) {
        const Eigen::Vector3d d =
            Eigen::Vector3d(x[3 * v], x[3 * v + 1], x[3 * v + 2]) - vertex(rest, v);
        EXPECT_LT((d - t).cwiseAbs().maxCoeff(), 1e-15) << "vertex " << v;
    }
    // Zero displacement: the rest positions, bit for bit in float.
    std::vector<float> xf(3 * em.vertexCount());
    ASSERT_TRUE(em.update(Eigen::VectorXd::Zero(mesh.dofCount()), std::span<float>(xf)));
    EXPECT_EQ(xf, rest.positions);
}

TEST(EmbeddedMesh, SharedFacesEdgesAndNodesAgreeFromEveryCell) {
    // Binary-fraction edge and origin, so float vertices lie exactly on faces and nodes.
    constexpr double h = 1.0 / 128;
    const std::array<int, 3> counts{4, 4, 4};
    const HexMesh full = HexMesh::box(Eigen::Vector3d::Constant(3 * h), counts);
    Eigen::VectorXd u(full.dofCount());
    std::mt19937 rng(3);
    std::uniform_real_distribution<double> disp(-1e-3, 1e-3);
    for (Eigen::Index i = 0; i < u.size(); ++i) u[i] = disp(rng);

    struct Case {
        Eigen::Vector3d p;  // lattice coordinates
        int sharing;        // cells whose closed box holds it
    };
    const Case cases[] = {
        {{1.0, 1.25, 1.5}, 2},   // face x = 1
        {{1.0, 2.0, 0.375}, 4},  // edge x = 1, y = 2
        {{1.0, 2.0, 1.0}, 8},    // node (1, 2, 1)
        {{0.5, 0.75, 0.25}, 1},  // inside cell (0, 0, 0)
    };
    for (const Case& c : cases) {
        const Eigen::Vector3d p = c.p * h;
        const TriangleMesh rest = pointsMesh({p});
        std::vector<Eigen::Vector3d> results;
        for (int cell = 0; cell < full.cellCount(); ++cell) {
            const Eigen::Vector3d n0 = full.nodePosition(full.cellNodes(cell)[0]) / h;
            if (((c.p - n0).array() < 0).any() || ((c.p - n0).array() > 1).any()) continue;
            // Only this cell active: the vertex must be tied to it, inside (not clamped).
            std::vector<double> youngs(static_cast<std::size_t>(full.cellCount()), 0.0);
            youngs[static_cast<std::size_t>(cell)] = 1.0;
            const HexMesh one = HexMesh::fromCells(counts, h, Eigen::Vector3d::Zero(), youngs);
            const EmbeddedMesh em(one, rest);
            EXPECT_EQ(em.cellOf(0), cell);
            EXPECT_EQ(em.clampedCount(), 0);
            std::vector<double> x(3);
            ASSERT_TRUE(em.update(u, std::span<double>(x)));
            results.emplace_back(x[0], x[1], x[2]);
        }
        ASSERT_EQ(static_cast<int>(results.size()), c.sharing) << c.p.transpose();
        for (const Eigen::Vector3d& r : results) {
            EXPECT_LT((r - results.front()).cwiseAbs().maxCoeff(), 1e-15) << c.p.transpose();
        }
        // Independent evaluation on the full mesh: trilinear interpolation written out over
        // the lattice nodes around p.
        Eigen::Vector3d expected = p;
        for (int n = 0; n < full.nodeCount(); ++n) {
            const Eigen::Vector3d d = (full.nodePosition(n) / h - c.p).cwiseAbs();
            if ((d.array() >= 1).any()) continue;
            expected += (1 - d.x()) * (1 - d.y()) * (1 - d.z()) * u.segment<3>(3 * n);
        }
        EXPECT_LT((results.front() - expected).cwiseAbs().maxCoeff(), 1e-15) << c.p.transpose();
        // The full mesh picks one of them and agrees too.
        const EmbeddedMesh em(full, rest);
        std::vector<double> x(3);
        ASSERT_TRUE(em.update(u, std::span<double>(x)));
        EXPECT_LT((Eigen::Vector3d(x[0], x[1], x[2]) - expected).cwiseAbs().maxCoeff(), 1e-15);
    }
}

TEST(EmbeddedMesh, VerticesOffTheTissueAreClampedToTheNearestCell) {
    // 4 x 2 x 2 cells of 10 mm; the cells with i = 3 are void, so x in [30, 40] mm is void.
    constexpr double h = 0.01;
    std::vector<double> youngs(16, 1.0);
    const HexMesh probe = HexMesh::box(Eigen::Vector3d(0.04, 0.02, 0.02), {5, 3, 3});
    for (int k = 0; k < 2; ++k)
        for (int j = 0; j < 2; ++j) youngs[static_cast<std::size_t>(probe.cell(3, j, k))] = 0.0;
    const HexMesh mesh = HexMesh::fromCells({5, 3, 3}, h, Eigen::Vector3d::Zero(), youngs);
    const std::vector<Eigen::Vector3d> points = {
        {0.035, 0.005, 0.012},   // void cell, 5 mm from the tissue (x = 30 mm)
        {0.012, -0.003, 0.015},  // outside the lattice below y = 0, 3 mm away
        {0.015, 0.012, 0.018},   // inside
        {0.034, 0.023, 0.021},   // void and outside: (4, 3, 1) mm from the corner (30, 20, 20)
    };
    const TriangleMesh rest = pointsMesh(points);
    const EmbeddedMesh em(mesh, rest);
    EXPECT_EQ(em.clampedCount(), 3);
    EXPECT_NEAR(em.maxClampDistance(), std::sqrt(16.0 + 9.0 + 1.0) * 1e-3, 1e-8);  // float vertices
    EXPECT_EQ(em.cellOf(0), mesh.cell(2, 0, 1));
    EXPECT_EQ(em.cellOf(1), mesh.cell(1, 0, 1));
    EXPECT_EQ(em.cellOf(3), mesh.cell(2, 1, 1));
    // A clamped vertex moves with the nearest point of its cell: for an affine field,
    // by A Xc + b with Xc the clamped rest point.
    const Eigen::VectorXd u = affineField(mesh, kA, kB);
    std::vector<double> x(3 * points.size());
    ASSERT_TRUE(em.update(u, std::span<double>(x)));
    for (std::size_t v = 0; v < points.size(); ++v) {
        const Eigen::Vector3d rv = vertex(rest, v);
        const Eigen::Vector3d lo = mesh.nodePosition(mesh.cellNodes(em.cellOf(v))[0]);
        const Eigen::Vector3d xc = rv.cwiseMax(lo).cwiseMin(lo + Eigen::Vector3d::Constant(h));
        EXPECT_EQ(xc == rv, v == 2) << "vertex " << v;
        const Eigen::Vector3d expected = rv + kA * xc + kB;
        const Eigen::Vector3d got(x[3 * v], x[3 * v + 1], x[3 * v + 2]);
        EXPECT_LT((got - expected).cwiseAbs().maxCoeff(), 1e-12) << "vertex " << v;
    }
    // Nodes read: those of the three cells in use.
    EXPECT_EQ(em.nodes().size(), 18u);  // cells (1..2, 0..1, 1): 3 x 3 x 2 nodes
    EXPECT_TRUE(std::is_sorted(em.nodes().begin(), em.nodes().end()));
}

TEST(EmbeddedMesh, UpdateAllocatesNothing) {
    const HexMesh mesh = HexMesh::box(Eigen::Vector3d(0.03, 0.03, 0.03), {7, 7, 7});
    std::vector<Eigen::Vector3d> points;
    std::mt19937 rng(5);
    std::uniform_real_distribution<double> coord(0.0, 0.03);
    for (int i = 0; i < 642; ++i) points.emplace_back(coord(rng), coord(rng), coord(rng));
    const EmbeddedMesh em(mesh, pointsMesh(points));
    const Eigen::VectorXd u = affineField(mesh, kA, kB);
    std::vector<float> xf(3 * em.vertexCount());
    std::vector<double> xd(3 * em.vertexCount());
    const std::uint64_t before = palp::test::allocationCount();
    bool ok = true;
    for (int i = 0; i < 100; ++i) {
        ok = em.update(u, std::span<float>(xf)) && ok;
        ok = em.update(u, std::span<double>(xd)) && ok;
    }
    EXPECT_EQ(palp::test::allocationCount() - before, 0u);
    EXPECT_TRUE(ok);
}

TEST(EmbeddedMesh, WrongSizesWriteNothing) {
    const HexMesh mesh = HexMesh::box(Eigen::Vector3d(0.01, 0.01, 0.01), {2, 2, 2});
    const EmbeddedMesh em(mesh, pointsMesh({{0.005, 0.005, 0.005}, {0.001, 0.002, 0.003}}));
    std::vector<float> x(6, 42.0f);
    EXPECT_FALSE(em.update(Eigen::VectorXd::Zero(mesh.dofCount() - 1), std::span<float>(x)));
    EXPECT_FALSE(em.update(Eigen::VectorXd::Zero(mesh.dofCount()), std::span<float>(x).first(5)));
    EXPECT_EQ(x, std::vector<float>(6, 42.0f));
}

TEST(EmbeddedMesh, BadInputIsRefusedByName) {
    const HexMesh mesh = HexMesh::box(Eigen::Vector3d(0.02, 0.02, 0.02), {3, 3, 3});
    expectThrowWith<ValueError>([&] { const EmbeddedMesh e(mesh, TriangleMesh{}); },
                                {"embedded mesh", "at least one vertex", "none"});
    expectThrowWith<ValueError>(
        [&] {
            const EmbeddedMesh e(HexMesh{}, pointsMesh({{0, 0, 0}}));
        },
        {"embedded mesh", "hex mesh with elements"});
    TriangleMesh ragged = pointsMesh({{0.001, 0.001, 0.001}});
    ragged.positions.push_back(0.0f);
    expectThrowWith<ValueError>([&] { const EmbeddedMesh e(mesh, ragged); },
                                {"embedded mesh positions", "multiple of 3", "4"});
    TriangleMesh badIndex = pointsMesh({{0.001, 0.001, 0.001}, {0.002, 0.001, 0.001}});
    badIndex.indices = {0, 1, 2};
    expectThrowWith<ValueError>([&] { const EmbeddedMesh e(mesh, badIndex); },
                                {"embedded mesh triangle 0 index", "below 2", "found 2"});
    const double nan = std::numeric_limits<double>::quiet_NaN();
    expectThrowWith<ValueError>(
        [&] {
            const EmbeddedMesh e(mesh, pointsMesh({{0.001, 0.001, 0.001}, {0.01, nan, 0.01}}));
        },
        {"embedded mesh vertex 1", "finite", "nan"});
    // 10 mm cells; 15 mm beyond the x = 20 mm face is farther than one edge; 1e30 m too.
    expectThrowWith<ValueError>(
        [&] {
            const EmbeddedMesh e(
                mesh, pointsMesh({{0.01, 0.01, 0.01}, {0.0, 0.0, 0.0}, {0.035, 0.01, 0.01}}));
        },
        {"embedded mesh vertex 2 at (0.035, 0.01, 0.01) m", "within one element edge (0.01 m)",
         "found none"});
    expectThrowWith<ValueError>(
        [&] {
            const EmbeddedMesh e(mesh, pointsMesh({{1e30, 0.0, 0.0}}));
        },
        {"embedded mesh vertex 0", "1e+30"});
    // Just within one edge (9 mm beyond the face at x = 20 mm) is accepted, clamped.
    const EmbeddedMesh edge(mesh, pointsMesh({{0.029, 0.01, 0.01}}));
    EXPECT_EQ(edge.clampedCount(), 1);
}

TEST(EmbeddedMesh, TumourInclusionEmbedsInTheVoxelisedPhantom) {
    // The tumour phantom voxelised into 5 mm elements, stiffer where the scan shows the
    // inclusion: its surface mesh lies inside tissue cells (nothing clamped), and the cell at
    // its centre is one of the stiff ones.
    volume::PhantomSpec spec;
    spec.params.scene = volume::PhantomScene::Tumour;
    spec.voxelSize = 1e-3;
    const volume::Volume vol = volume::makePhantomVolume(spec);
    VoxelizeOptions options;
    options.elementSize = 5e-3;
    options.youngsFromValue = [](double hu) { return hu > 120 ? 50e3 : 5e3; };
    const VoxelizedMesh vm = voxelizeVolume(vol, options);
    const volume::Phantom phantom(spec.params);
    const EmbeddedMesh em(vm.mesh, phantom.inclusionMesh());
    EXPECT_EQ(em.vertexCount(), 642u);
    EXPECT_EQ(em.clampedCount(), 0);
    const EmbeddedMesh centre(vm.mesh, pointsMesh({phantom.inclusion().centre}));
    EXPECT_EQ(vm.mesh.cellYoungs()[static_cast<std::size_t>(centre.cellOf(0))], 50e3);
    // A rigid translation of the block carries the inclusion's centroid with it.
    const Eigen::Vector3d t(1e-3, 2e-3, -0.5e-3);
    Eigen::VectorXd u(vm.mesh.dofCount());
    for (int n = 0; n < vm.mesh.nodeCount(); ++n) u.segment<3>(3 * n) = t;
    std::vector<double> x(3 * em.vertexCount());
    ASSERT_TRUE(em.update(u, std::span<double>(x)));
    Eigen::Vector3d centroid = Eigen::Vector3d::Zero();
    for (std::size_t v = 0; v < em.vertexCount(); ++v)
        centroid += Eigen::Vector3d(x[3 * v], x[3 * v + 1], x[3 * v + 2]);
    centroid /= static_cast<double>(em.vertexCount());
    EXPECT_LT((centroid - phantom.inclusion().centre - t).norm(), 1e-6);
}

}  // namespace
}  // namespace palp::fem
