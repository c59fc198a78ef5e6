#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <string>

#include "palp/base/error.h"
#include "palp/fem/components.h"
#include "palp/fem/fem_model.h"
#include "palp/fem/implicit_solver.h"
#include "palp/fem/voxelize.h"
#include "palp/volume/load.h"
#include "palp/volume/phantom.h"
#include "test_support.h"

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

TEST(Voxelize, KeptIslandsAreDroppedWhenNothingHoldsThem) {
    VoxelizeOptions o = options();
    o.keepLargestComponent = false;
    const VoxelizedMesh v = voxelizeVolume(phantom(), o);
    EXPECT_EQ(v.mesh.elementCount(), 217);
    EXPECT_EQ(v.mesh.connectedComponents(), 2);
    EXPECT_NO_THROW(FemModel(v.mesh, ElasticMaterial{}));
    // Supported on its bottom face, the body stays and the island (not on that face) goes.
    const AnchoredBody body = anchorBody(v.mesh, v.mesh.faceNodes(BoxFace::zMin));
    EXPECT_EQ(body.kept.size(), 1u);
    EXPECT_EQ(body.dropped.size(), 1u);
    EXPECT_EQ(body.mesh.elementCount() + body.droppedCells, 217);
    EXPECT_EQ(body.droppedCells, 1);
}

/// A 1 mm scan: a 60 mm cube of tissue (40) around a closed bone box (1000) two 5 mm cells thick
/// (voxels 10..49 per axis) with tissue inside it (voxels 20..39): a brain in a skull.
volume::Volume boneBox() {
    volume::initialize();
    auto grid = openvdb::FloatGrid::create(-1000.0f);
    grid->setTransform(openvdb::math::Transform::createLinearTransform(1e-3));
    grid->setName(volume::kScanGridName);
    grid->fill(openvdb::CoordBBox({0, 0, 0}, {59, 59, 59}), 40.0f, true);
    grid->fill(openvdb::CoordBBox({10, 10, 10}, {49, 49, 49}), 1000.0f, true);
    grid->fill(openvdb::CoordBBox({20, 20, 20}, {39, 39, 39}), 40.0f, true);
    return volume::Volume{grid, {}};
}

TEST(Voxelize, TissueInsideABoneBoxIsDroppedAndTheOutsideKept) {
    VoxelizeOptions o = options();
    const VoxelizedMesh keep = voxelizeVolume(boneBox(), o);
    // 12^3 cells (centres 2, 7, .., 57 mm), all tissue or bone.
    ASSERT_EQ(keep.mesh.cellCounts(), (std::array<int, 3>{12, 12, 12}));
    EXPECT_EQ(keep.mesh.elementCount(), 1728);
    EXPECT_EQ(keep.insideBoneCells, 0);
    o.insideBone = InsideBone::drop;
    const VoxelizedMesh drop = voxelizeVolume(boneBox(), o);
    const HexMesh& m = drop.mesh;
    // Bone cells 2..9 per axis, the core 4..7: the 4^3 core goes (bone on both sides along x,
    // y and z) and so does the bone box's inner layer (6^3 - 4^3 cells touching only the core);
    // the outer layer (8^3 - 6^3) stays under the tissue outside.
    EXPECT_EQ(drop.insideBoneCells, 64 + 152);
    EXPECT_EQ(m.elementCount(), 1728 - 64 - 152);
    EXPECT_EQ(drop.droppedCells, 0);
    for (int k = 0; k < 12; ++k) {
        for (int j = 0; j < 12; ++j) {
            for (int i = 0; i < 12; ++i) {
                const auto inside = [](int a, int lo, int hi) { return a >= lo && a <= hi; };
                const bool core = inside(i, 4, 7) && inside(j, 4, 7) && inside(k, 4, 7);
                const bool innerLayer =
                    inside(i, 3, 8) && inside(j, 3, 8) && inside(k, 3, 8) && !core;
                EXPECT_EQ(m.cellActive(m.cell(i, j, k)), !core && !innerLayer) << i << j << k;
            }
        }
    }
    // The kept bone is the outer layer's nodes (nodes 2..10 per axis less the 5^3 that only
    // dropped cells share), all fixed; those 5^3 are the only inactive nodes.
    EXPECT_EQ(drop.boneNodes.size(), 9u * 9u * 9u - 5u * 5u * 5u);
    EXPECT_EQ(std::count(m.nodeActive().begin(), m.nodeActive().end(), true),
              13 * 13 * 13 - 5 * 5 * 5);
    // The surface is the cube's outside, 6 faces of 12 x 12 squares, and the bone box's inner
    // faces around the cavity, 6 faces of 6 x 6.
    EXPECT_EQ(m.boundarySurface().triangles.size(), (6u * 144u + 6u * 36u) * 2u);
}

TEST(Voxelize, TissueUnderABoneSlabOpenAtTheSidesIsKept) {
    // The synthetic scan's slab, turned: tissue above and below a bone slab that stops 10 mm
    // short of the block's sides, like the bone phantom's. Nothing is enclosed.
    volume::initialize();
    auto grid = openvdb::FloatGrid::create(-1000.0f);
    grid->setTransform(openvdb::math::Transform::createLinearTransform(1e-3));
    grid->setName(volume::kScanGridName);
    grid->fill(openvdb::CoordBBox({0, 0, 0}, {39, 39, 39}), 40.0f, true);
    grid->fill(openvdb::CoordBBox({10, 10, 20}, {29, 29, 24}), 1000.0f, true);
    const volume::Volume scan{grid, {}};
    VoxelizeOptions o = options();
    const VoxelizedMesh keep = voxelizeVolume(scan, o);
    o.insideBone = InsideBone::drop;
    const VoxelizedMesh drop = voxelizeVolume(scan, o);
    EXPECT_EQ(keep.mesh.elementCount(), 512);
    EXPECT_EQ(drop.mesh.elementCount(), 512);
    EXPECT_EQ(drop.insideBoneCells, 0);
    EXPECT_EQ(drop.boneNodes, keep.boneNodes);
}

TEST(Voxelize, DroppingTissueInsideBoneLeavesThePhantomsAsTheyWere) {
    for (const auto scene : {volume::PhantomScene::Bone, volume::PhantomScene::Tumour}) {
        volume::PhantomSpec spec;
        spec.params.scene = scene;
        spec.voxelSize = 2e-3;
        const volume::Volume vol = volume::makePhantomVolume(spec);
        VoxelizeOptions o;
        o.boneThreshold = 500;
        const VoxelizedMesh keep = voxelizeVolume(vol, o);
        o.insideBone = InsideBone::drop;
        const VoxelizedMesh drop = voxelizeVolume(vol, o);
        SCOPED_TRACE(static_cast<int>(scene));
        EXPECT_GT(keep.mesh.elementCount(), 1000);
        EXPECT_EQ(drop.mesh.elementCount(), keep.mesh.elementCount());
        EXPECT_EQ(drop.mesh.cellYoungs(), keep.mesh.cellYoungs());
        EXPECT_EQ(drop.boneNodes, keep.boneNodes);
        EXPECT_EQ(drop.insideBoneCells, 0);
        if (scene == volume::PhantomScene::Bone) {
            EXPECT_GT(keep.boneNodes.size(), 100u);
        }
    }
}

TEST(Voxelize, HeadCtKeepsTheSkinOnTheSkullAndDropsTheBrain) {
    PALP_REQUIRE_DATA(dir, "ct-ge-head-tilt");
    volume::LoadOptions load;
    load.resample.voxelSize = 2e-3;  // coarse: the 5 mm cells need no more
    const volume::Volume head = volume::load({dir}, load);
    VoxelizeOptions o;  // palp palpate --deformable's thresholds: -200 and 500 HU, 5 mm cells
    o.boneThreshold = 500;
    const VoxelizedMesh keep = voxelizeVolume(head, o);
    o.insideBone = InsideBone::drop;
    const VoxelizedMesh drop = voxelizeVolume(head, o);
    const HexMesh& k = keep.mesh;
    const HexMesh& d = drop.mesh;
    ASSERT_EQ(d.cellCounts(), k.cellCounts());
    std::printf(
        "head CT at 5 mm: %d elements keeping tissue inside bone, %d dropping it "
        "(%d cells inside bone, %zu -> %zu bone nodes)\n",
        k.elementCount(), d.elementCount(), drop.insideBoneCells, keep.boneNodes.size(),
        drop.boneNodes.size());
    // 26,016 -> 15,036 elements at 2 mm voxels (the brain: 10,846 cells).
    EXPECT_LT(d.elementCount(), 0.65 * k.elementCount());
    EXPECT_GT(drop.insideBoneCells, 8000);
    // What a finger meets from the front, back and sides is unchanged: along every lattice line
    // across the scan (x and y; the slices run along z, and the scan's first and last slices cut
    // through the brain, which is not skin), the first and the last tissue cells are kept.
    const auto c = k.cellCounts();
    int lines = 0, lost = 0;
    for (int a = 0; a < 2; ++a) {
        const int b = (a + 1) % 3, e = (a + 2) % 3;
        for (int ie = 0; ie < c[static_cast<std::size_t>(e)]; ++ie) {
            for (int ib = 0; ib < c[static_cast<std::size_t>(b)]; ++ib) {
                int first = -1, last = -1;
                for (int t = 0; t < c[static_cast<std::size_t>(a)]; ++t) {
                    std::array<int, 3> ijk{};
                    ijk[static_cast<std::size_t>(a)] = t;
                    ijk[static_cast<std::size_t>(b)] = ib;
                    ijk[static_cast<std::size_t>(e)] = ie;
                    if (!k.cellActive(k.cell(ijk[0], ijk[1], ijk[2]))) continue;
                    if (first < 0) first = k.cell(ijk[0], ijk[1], ijk[2]);
                    last = k.cell(ijk[0], ijk[1], ijk[2]);
                }
                if (first < 0) continue;
                ++lines;
                lost += (d.cellActive(first) ? 0 : 1) + (d.cellActive(last) ? 0 : 1);
            }
        }
    }
    EXPECT_GT(lines, 1000);
    // A few skin cells go with islands that only the brain joined to the rest (3 of ~2,500
    // lines at 2 mm voxels).
    EXPECT_LE(lost, lines / 100) << lines;
    // The bone left is the skull's outside, under the kept tissue: every kept bone node is a
    // node of a kept cell, and a kept node that was fixed is fixed still.
    EXPECT_LT(drop.boneNodes.size(), keep.boneNodes.size());
    for (int n : drop.boneNodes) EXPECT_TRUE(d.nodeActive()[static_cast<std::size_t>(n)]);
    for (int n : keep.boneNodes) {
        if (d.nodeActive()[static_cast<std::size_t>(n)]) {
            EXPECT_TRUE(std::binary_search(drop.boneNodes.begin(), drop.boneNodes.end(), n)) << n;
        }
    }
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
