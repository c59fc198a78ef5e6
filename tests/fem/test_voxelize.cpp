#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <string>

#include "palp/base/error.h"
#include "palp/fem/fem_model.h"
#include "palp/fem/implicit_solver.h"
#include "palp/fem/voxelize.h"

namespace palp::fem {
namespace {

/// A synthetic 1 mm scan: a 30 mm cube of soft tissue (40) with a stiffer 10 mm core (80) and a
/// 5 mm bone slab (1000) at the bottom, air (-1000) around, and a 3-voxel island far away.
volume::Volume phantom(bool island = true) {
    volume::initialize();
    auto grid = openvdb::FloatGrid::create(-1000.0f);
    grid->setTransform(openvdb::math::Transform::createLinearTransform(1e-3));
    grid->setName(volume::kScanGridName);
    grid->fill(openvdb::CoordBBox({0, 0, 0}, {29, 29, 29}), 40.0f, true);
    grid->fill(openvdb::CoordBBox({10, 10, 10}, {19, 19, 19}), 80.0f, true);
    grid->fill(openvdb::CoordBBox({0, 0, 0}, {29, 29, 4}), 1000.0f, true);
    if (island) grid->fill(openvdb::CoordBBox({50, 50, 50}, {52, 52, 52}), 40.0f, true);
    return volume::Volume{grid, {}};
}

VoxelizeOptions options() {
    VoxelizeOptions o;
    o.elementSize = 5e-3;
    o.tissueThreshold = 0.0;
    o.boneThreshold = 500.0;
    o.youngsFromValue = [](double v) { return 100.0 * v; };  // Pa per scan unit
    return o;
}

TEST(Voxelize, TissueMaterialAndBoneFromASyntheticScan) {
    const VoxelizedMesh v = voxelizeVolume(phantom(), options());
    const HexMesh& m = v.mesh;
    EXPECT_DOUBLE_EQ(m.edge(), 5e-3);
    // The lattice starts at the corner of the first voxel (centre 0, half a voxel below).
    EXPECT_NEAR((m.origin() - Eigen::Vector3d::Constant(-0.5e-3)).norm(), 0.0, 1e-12);
    // Voxels span -0.5 .. 52.5 mm: 11 cells of 5 mm per axis.
    EXPECT_EQ(m.cellCounts(), (std::array<int, 3>{11, 11, 11}));
    // Cell centres at 2, 7, ..., 27 mm lie in the 30 mm cube: 6^3 tissue cells; the island's
    // one cell (centre 52 mm) is dropped as a separate body.
    EXPECT_EQ(m.elementCount(), 216);
    EXPECT_EQ(v.droppedCells, 1);
    EXPECT_FALSE(m.cellActive(m.cell(10, 10, 10)));
    // Per-element E from the transfer function of the centre value.
    EXPECT_DOUBLE_EQ(m.cellYoungs()[static_cast<std::size_t>(m.cell(0, 0, 3))], 4e3);
    EXPECT_DOUBLE_EQ(m.cellYoungs()[static_cast<std::size_t>(m.cell(2, 3, 2))], 8e3);
    EXPECT_DOUBLE_EQ(m.cellYoungs()[static_cast<std::size_t>(m.cell(5, 5, 0))], 1e5);
    EXPECT_DOUBLE_EQ(m.cellYoungs()[static_cast<std::size_t>(m.cell(6, 0, 0))], 0.0);
    // Bone: the bottom layer of cells, 7 x 7 x 2 nodes.
    ASSERT_EQ(v.boneNodes.size(), 98u);
    EXPECT_TRUE(std::is_sorted(v.boneNodes.begin(), v.boneNodes.end()));
    for (int n : v.boneNodes) {
        EXPECT_LE(m.nodeCoords(n)[2], 1);
        EXPECT_TRUE(m.nodeActive()[static_cast<std::size_t>(n)]);
    }
    // The boundary surface closes around the 30 mm cube: 6 faces of 6 x 6 squares.
    EXPECT_EQ(m.boundarySurface().triangles.size(), 6u * 36u * 2u);
}

TEST(Voxelize, BoneNodesSupportAStaticSolve) {
    const VoxelizedMesh v = voxelizeVolume(phantom(), options());
    ElasticMaterial material;
    const FemModel model(v.mesh, material);
    Constraints c(model.dofCount());
    c.fixNodes(v.boneNodes);
    Eigen::VectorXd f = Eigen::VectorXd::Zero(model.dofCount());
    const int top = v.mesh.node(3, 3, 6);
    ASSERT_TRUE(v.mesh.nodeActive()[static_cast<std::size_t>(top)]);
    f[3 * top + 2] = -1e-3;
    ImplicitSolver s(model, c, {Integrator::quasiStatic, LinearSolverKind::cholmod});
    s.externalForce() = f;
    EXPECT_EQ(s.step(1.0).flags, kStepOk);
    EXPECT_LT(s.displacement()[3 * top + 2], 0.0);
    EXPECT_TRUE(s.displacement().allFinite());
    EXPECT_NEAR(s.reactionSum(v.boneNodes).z(), 1e-3, 1e-9) << "bone carries the load";
}

TEST(Voxelize, KeepingIslandsGivesADisconnectedMeshThatTheModelRejects) {
    VoxelizeOptions o = options();
    o.keepLargestComponent = false;
    const VoxelizedMesh v = voxelizeVolume(phantom(), o);
    EXPECT_EQ(v.mesh.elementCount(), 217);
    EXPECT_EQ(v.mesh.connectedComponents(), 2);
    EXPECT_THROW(FemModel(v.mesh, ElasticMaterial{}), ValueError);
}

TEST(Voxelize, BadInputNamesTheValue) {
    const volume::Volume scan = phantom(false);
    const auto expectError = [&](const VoxelizeOptions& o, const std::string& needle) {
        try {
            (void)voxelizeVolume(scan, o);
            ADD_FAILURE() << "expected a ValueError mentioning " << needle;
        } catch (const ValueError& e) {
            EXPECT_NE(std::string(e.what()).find(needle), std::string::npos) << e.what();
        }
    };
    VoxelizeOptions o = options();
    o.elementSize = 0.0;
    expectError(o, "voxelize elementSize: expected a value in [1e-06, 0.1] m, found 0");
    o.elementSize = 1e300;
    expectError(o, "voxelize elementSize: expected a value in [1e-06, 0.1] m, found 1e+300");
    o = options();
    o.tissueThreshold = std::nan("");
    expectError(o, "voxelize tissueThreshold: expected a value in [-1e+09, 1e+09], found nan");
    o = options();
    o.boneThreshold = -HUGE_VAL;
    expectError(o, "voxelize boneThreshold: expected a value in [-1e+09, 1e+09], found -inf");
    o = options();
    o.tissueThreshold = 5000.0;
    expectError(o, "found none");
    o = options();
    o.youngsFromValue = [](double v) { return v > 60.0 ? 0.0 : 1e3; };
    expectError(o, "found 0 Pa");
    o = options();
    o.elementSize = 1e-5;
    o.maxCells = 1'000'000;
    expectError(o, "larger element size");
    volume::Volume empty{openvdb::FloatGrid::create(-1000.0f), {}};
    try {
        (void)voxelizeVolume(empty, options());
        ADD_FAILURE() << "empty grid accepted";
    } catch (const ValueError& e) {
        EXPECT_NE(std::string(e.what()).find("active voxels"), std::string::npos);
    }
}

}  // namespace
}  // namespace palp::fem
