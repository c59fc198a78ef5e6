#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <cmath>

#include "palp/base/error.h"
#include "palp/fem/components.h"
#include "palp/fem/fem_model.h"
#include "palp/fem/hex_mesh.h"
#include "palp/fem/material.h"

namespace palp::fem {
namespace {

TEST(HexMesh, BoxNumberingAndFaces) {
    const HexMesh m =
        HexMesh::box(Eigen::Vector3d(0.04, 0.02, 0.03), {5, 3, 4}, 7.0, Eigen::Vector3d(1, 2, 3));
    EXPECT_EQ(m.nodeCount(), 60);
    EXPECT_EQ(m.elementCount(), 4 * 2 * 3);
    EXPECT_DOUBLE_EQ(m.edge(), 0.01);
    EXPECT_EQ(m.node(1, 2, 3), 1 + 5 * (2 + 3 * 3));
    EXPECT_TRUE(m.nodePosition(m.node(4, 2, 3)).isApprox(Eigen::Vector3d(1.04, 2.02, 3.03)));
    EXPECT_EQ(m.faceNodes(BoxFace::zMin).size(), 15u);
    EXPECT_EQ(m.faceNodes(BoxFace::xMax).size(), 12u);
    for (int n : m.faceNodes(BoxFace::yMax)) EXPECT_EQ(m.nodeCoords(n)[1], 2);
    const auto nodes = m.cellNodes(m.cell(1, 1, 2));
    EXPECT_EQ(nodes[0], m.node(1, 1, 2));
    EXPECT_EQ(nodes[7], m.node(2, 2, 3));
    EXPECT_EQ(m.connectedComponents(), 1);
}

TEST(HexMesh, BoundarySurfaceIsClosedAndOutward) {
    // An L-shaped body: a 3x3x3 block of cells with one corner cell removed.
    std::vector<double> e(27, 1.0);
    e[26] = 0.0;
    const HexMesh m = HexMesh::fromCells({4, 4, 4}, 0.5, Eigen::Vector3d::Zero(), e);
    const SurfaceMesh s = m.boundarySurface();
    // 6 faces x 9 quads, minus 3 removed outer quads, plus 3 inner quads = 54.
    EXPECT_EQ(s.triangles.size(), 2u * 54u);
    // Divergence theorem: sum of signed tetrahedron volumes equals the body volume.
    double volume = 0.0;
    for (const auto& t : s.triangles) {
        const Eigen::Vector3d a = s.vertices[t[0]].cast<double>();
        const Eigen::Vector3d b = s.vertices[t[1]].cast<double>();
        const Eigen::Vector3d c = s.vertices[t[2]].cast<double>();
        volume += a.dot(b.cross(c)) / 6.0;
    }
    EXPECT_NEAR(volume, 26 * 0.125, 1e-6);
}

TEST(HexMesh, BadInputThrowsWithValue) {
    EXPECT_THROW(HexMesh::box(Eigen::Vector3d::Constant(1.0), {1, 3, 3}), ValueError);
    EXPECT_THROW(HexMesh::box(Eigen::Vector3d(1.0, -1.0, 1.0), {3, 3, 3}), ValueError);
    EXPECT_THROW(HexMesh::box(Eigen::Vector3d(1.0, 2.0, 1.0), {3, 3, 3}), ValueError);
    EXPECT_THROW(
        HexMesh::fromCells({3, 3, 3}, 0.1, Eigen::Vector3d::Zero(), std::vector<double>(8, 0.0)),
        ValueError);  // empty
    try {
        HexMesh::fromCells({3, 3, 3}, -0.1, Eigen::Vector3d::Zero(), std::vector<double>(8, 1.0));
        FAIL() << "expected a ValueError";
    } catch (const ValueError& e) {
        EXPECT_NE(std::string(e.what()).find("found -0.1"), std::string::npos) << e.what();
    }
}

TEST(HexMesh, PiecesTheSupportsDoNotHoldAreRefusedOrDropped) {
    std::vector<double> e(27, 0.0);
    e[0] = 1.0;
    e[26] = 1.0;  // opposite corners: no shared node
    const HexMesh m = HexMesh::fromCells({4, 4, 4}, 0.01, Eigen::Vector3d::Zero(), e);
    EXPECT_EQ(m.connectedComponents(), 2);
    // The model takes both pieces; the supports must hold each.
    EXPECT_NO_THROW(FemModel(m, ElasticMaterial{}));
    const std::vector<int> face = m.faceNodes(BoxFace::zMin);  // holds the first piece only
    try {
        requireAnchored(m, face);
        FAIL() << "expected a ValueError";
    } catch (const ValueError& err) {
        EXPECT_NE(std::string(err.what()).find("piece 2 of 2 (1 cells, 0 fixed nodes"),
                  std::string::npos)
            << err.what();
    }
    // anchorBody drops it and crops the lattice to the piece held (padded to 4 cells a side).
    const AnchoredBody body = anchorBody(m, face);
    ASSERT_EQ(body.kept.size(), 1u);
    ASSERT_EQ(body.dropped.size(), 1u);
    EXPECT_EQ(body.droppedCells, 1);
    EXPECT_EQ(body.mesh.elementCount(), 1);
    EXPECT_EQ(body.mesh.cellCounts(), (std::array<int, 3>{4, 4, 4}));
    EXPECT_EQ(body.fixedNodes.size(), 4u);  // the held piece's face
    EXPECT_NO_THROW(requireAnchored(body.mesh, body.fixedNodes));
    // Held by both ends, both stay.
    std::vector<int> both = face;
    const std::vector<int> top = m.faceNodes(BoxFace::zMax);
    both.insert(both.end(), top.begin(), top.end());
    EXPECT_NO_THROW(requireAnchored(m, both));
    EXPECT_EQ(anchorBody(m, both).kept.size(), 2u);
}

TEST(HexMesh, APieceOnAnEdgeOrOnALineOfFixedNodesIsNotHeld) {
    // Two cells sharing one edge: two pieces (a hexahedron turns about a shared edge).
    std::vector<double> e(4, 0.0);
    e[0] = 1.0;  // cell (0, 0, 0)
    e[3] = 1.0;  // cell (1, 1, 0): shares the edge x = y = 1 with the first
    const HexMesh m = HexMesh::fromCells({3, 3, 2}, 0.01, Eigen::Vector3d::Zero(), e);
    std::vector<std::uint8_t> fixed(static_cast<std::size_t>(m.nodeCount()), 0);
    for (int n : m.faceNodes(BoxFace::xMin)) fixed[static_cast<std::size_t>(n)] = 1;
    const std::vector<BodyPiece> pieces = bodyPieces(m, fixed);
    ASSERT_EQ(pieces.size(), 2u);
    EXPECT_TRUE(pieces[0].anchored);  // the first cell's x = 0 face: four fixed nodes
    EXPECT_FALSE(pieces[1].anchored);
    // Fixed nodes on one line (the shared edge) do not hold a piece either.
    std::fill(fixed.begin(), fixed.end(), 0);
    fixed[static_cast<std::size_t>(m.node(1, 1, 0))] = 1;
    fixed[static_cast<std::size_t>(m.node(1, 1, 1))] = 1;
    for (const BodyPiece& p : bodyPieces(m, fixed)) {
        EXPECT_EQ(p.fixedNodes, 2);
        EXPECT_FALSE(p.anchored);
    }
}

TEST(Material, ValidationNamesTheValue) {
    auto expectBad = [](ElasticMaterial m, const std::string& fragment) {
        try {
            validate(m);
            FAIL() << "expected a ValueError for " << fragment;
        } catch (const ValueError& e) {
            EXPECT_NE(std::string(e.what()).find(fragment), std::string::npos) << e.what();
        }
    };
    ElasticMaterial m;
    m.poissonRatio = 0.5;
    expectBad(m, "found 0.5");
    m.poissonRatio = -1.0;
    expectBad(m, "material poissonRatio: expected a value in (-1, 0.5), found -1");
    m = ElasticMaterial{};
    m.youngsModulus = 0.0;
    expectBad(m, "material youngsModulus: expected a value in [1, 1e+12] Pa, found 0");
    m.youngsModulus = 1e300;  // finite but absurd (issue 20: --young-kpa 1e300)
    expectBad(m, "material youngsModulus: expected a value in [1, 1e+12] Pa, found 1e+300");
    m = ElasticMaterial{};
    m.density = -2.0;
    expectBad(m, "material density: expected a value in [1, 100000] kg/m^3, found -2");
    m = ElasticMaterial{};
    m.dampingAlpha = 1e20;  // --fem-damping 1e20
    expectBad(m, "material dampingAlpha: expected a value in [0, 10000] 1/s, found 1e+20");
    m.dampingAlpha = std::nan("");
    expectBad(m, "material dampingAlpha: expected a value in [0, 10000] 1/s, found nan");
    m = ElasticMaterial{};
    m.dampingBeta = 1e20;  // --fem-beta 1e20
    expectBad(m, "material dampingBeta: expected a value in [0, 1] s, found 1e+20");
    m.dampingBeta = -HUGE_VAL;
    expectBad(m, "material dampingBeta: expected a value in [0, 1] s, found -inf");
    m = ElasticMaterial{};
    m.poissonRatio = 0.499;
    EXPECT_NO_THROW(validate(m));
    m.poissonRatio = -0.9;
    EXPECT_NO_THROW(validate(m));
    // c_d for soft tissue: sqrt(5000 * 0.55 / (1000 * 1.45 * 0.1)) = 4.3549 m/s.
    const ElasticMaterial tissue{5e3, 0.45, 1e3, 0, 0};
    EXPECT_NEAR(tissue.dilatationalWaveSpeed(), std::sqrt(5000 * 0.55 / (1000 * 1.45 * 0.1)),
                1e-12);
}

}  // namespace
}  // namespace palp::fem
