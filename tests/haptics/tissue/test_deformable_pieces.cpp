// A voxelised body that is not one clean block (issue: any voxelised body is solvable): a thin
// shell on a support slab with two islands floating beside it and a flap hanging on a corner.
// The pieces the supports hold stay, the others are dropped and reported, and the regions solve
// it with the whole mesh's displacement under a held force within 5 %.
#include <gtest/gtest.h>

#include <cmath>
#include <memory>
#include <string>
#include <vector>

#include "deformable_fixtures.h"
#include "palp/fem/components.h"
#include "palp/haptics/tissue/deformable.h"
#include "palp/haptics/tissue/deformable_setup.h"
#include "palp/volume/volume.h"

namespace palp::haptics {
namespace {

using namespace dfix;

constexpr double kVoxel = 1e-3;  // scan voxel, m
constexpr double kCell = 5e-3;   // element edge, m

/// Voxels (1 mm) of box [lo, hi] (mm, inclusive) set to @p value.
void fillMm(openvdb::FloatGrid& g, openvdb::Coord lo, openvdb::Coord hi, float value) {
    g.fill(openvdb::CoordBBox(lo, hi), value, true);
}

/// A 1 mm scan, -1000 HU air: a 10 mm slab on y 40..49 (the support side), a dome-like shell
/// one 5 mm cell thick standing on it (an open box 50 x 35 x 50 mm, walls 5 mm), two 10 mm
/// islands in the air beside it, and a 5 mm flap touching the shell only at a corner.
volume::Volume piecesScan() {
    volume::initialize();
    auto grid = openvdb::FloatGrid::create(-1000.0f);
    grid->setTransform(openvdb::math::Transform::createLinearTransform(kVoxel));
    grid->setName(volume::kScanGridName);
    fillMm(*grid, {0, 40, 0}, {59, 49, 59}, 40.0f);       // slab
    fillMm(*grid, {5, 5, 5}, {54, 39, 54}, 40.0f);        // the shell's block...
    fillMm(*grid, {10, 10, 10}, {49, 39, 49}, -1000.0f);  // ...hollowed: walls one cell thick
    fillMm(*grid, {60, 10, 10}, {69, 19, 19}, 40.0f);     // island 1 (x 60..69: off the shell)
    fillMm(*grid, {60, 25, 40}, {69, 34, 49}, 40.0f);     // island 2
    fillMm(*grid, {0, 0, 55}, {4, 4, 59}, 40.0f);         // flap: meets the shell at a corner
    return volume::Volume{grid, {}};
}

DeformableSetup piecesSetup(DeformableSolver solver) {
    DeformableSetup s;
    s.voxelize.elementSize = kCell;
    s.voxelize.tissueThreshold = -200;
    s.voxelize.boneThreshold = std::numeric_limits<double>::infinity();
    s.voxelize.insideBone = fem::InsideBone::keep;
    s.material = softTissue();
    s.supportFace = fem::BoxFace::yMax;  // the slab's far face
    s.options.filterWidth = 3e-3;
    s.options.solverKind = solver;
    s.options.regions.threaded = false;
    s.options.regions.primaryNodes = 30;
    s.options.regionsCentre = mm(30, 0, 30);
    // The fine secondary: a coarse one (lod 2) on this one-cell shell is 33 % stiffer than the
    // whole mesh (4.02 against 6.00 mm here), its trilinear corners spanning twice the wall.
    s.options.regions.lod = 1;
    return s;
}

TEST(DeformablePieces, HeldPiecesStayTheOthersAreDroppedAndReported) {
    const volume::Volume scan = piecesScan();
    const auto model = makeDeformableModel(scan, piecesSetup(DeformableSolver::wholeMeshExplicit));
    // The shell and slab are one piece held by the support face; the islands and the flap
    // (a corner is a hinge) are not held.
    ASSERT_EQ(model->keptPieces().size(), 1u);
    EXPECT_TRUE(model->keptPieces()[0].anchored);
    ASSERT_EQ(model->droppedPieces().size(), 3u);
    int dropped = 0;
    for (const fem::BodyPiece& p : model->droppedPieces()) {
        EXPECT_FALSE(p.anchored);
        dropped += p.cells;
    }
    EXPECT_EQ(dropped, 2 * 8 + 1);  // two 2x2x2-cell islands and the one-cell flap
    // The lattice holds the kept piece: every node of an element, and a 4-cell multiple.
    const fem::HexMesh& mesh = model->model().mesh();
    for (int a = 0; a < 3; ++a) EXPECT_EQ(mesh.cellCounts()[static_cast<std::size_t>(a)] % 4, 0);
    EXPECT_NO_THROW(fem::requireAnchored(mesh, model->fixedNodes()));
    // Nothing dropped is left in the mesh: x stops at the slab's 60 mm.
    for (int n = 0; n < mesh.nodeCount(); ++n) {
        if (mesh.nodeActive()[static_cast<std::size_t>(n)]) {
            EXPECT_LE(mesh.nodePosition(n).x(), 60e-3 + 1e-9);
        }
    }
}

TEST(DeformablePieces, RegionsOnTheShellAgreeWithTheWholeMesh) {
    const volume::Volume scan = piecesScan();
    const auto regions = makeDeformableModel(scan, piecesSetup(DeformableSolver::asyncRegions));
    const auto whole = makeDeformableModel(scan, piecesSetup(DeformableSolver::wholeMeshExplicit));
    ASSERT_EQ(regions->options().solverKind, DeformableSolver::asyncRegions);
    // A constant load on the shell's top (y = 5 mm, the face against the press), settled.
    const Eigen::Vector3d at = mm(30, 5, 30), force(0.0, 0.05, 0.0);
    DeformableBody a(regions), b(whole);
    const int node = a.applyContactForce(at, force);
    ASSERT_EQ(b.applyContactForce(at, force), node);
    for (int i = 0; i < 2000; ++i) {
        ASSERT_EQ(a.step(kT), 0u) << "tick " << i;
        b.step(kT);
    }
    const double ua = a.displacement()[3 * node + 1], ub = b.displacement()[3 * node + 1];
    const Eigen::VectorXd ref = quasiStatic(*whole, b.nodalForce());
    EXPECT_GT(ref[3 * node + 1], 1e-4);
    // The contact's stiffness (force over displacement) of the regions within 5 % of the whole
    // mesh's, and of the quasi-static solve.
    EXPECT_NEAR(ua, ub, 0.05 * ub);
    EXPECT_NEAR(ua, ref[3 * node + 1], 0.05 * ref[3 * node + 1]);
}

TEST(DeformablePieces, TheSkinUnderAPatchIsTheLayerThePressMeetsFirst) {
    // On a curved body the regions' slide zone comes from the skin under the path: the free
    // surface nodes in the rectangle that the press meets first, not the surfaces behind them.
    const volume::Volume scan = piecesScan();
    DeformableSetup setup = piecesSetup(DeformableSolver::asyncRegions);
    const SlidePatch patch{mm(30, 5, 30),
                           Eigen::Vector3d::UnitX(),
                           Eigen::Vector3d::UnitZ(),
                           Eigen::Vector3d::UnitY(),
                           40e-3,
                           40e-3};
    setup.slidePatch = patch;
    const auto model = makeDeformableModel(scan, setup);
    const std::vector<int> skin = skinNodesUnder(*model, patch);
    EXPECT_EQ(model->options().regions.slideNodes, skin);
    const fem::HexMesh& mesh = model->model().mesh();
    int top = 0;
    for (const int n : skin) {
        const Eigen::Vector3d p = mesh.nodePosition(n);
        // In the rectangle, and on the shell's top (nodes lie on voxel corners: y 4.5 mm) or
        // its one-cell-thin ceiling (9.5 mm) right behind it; never the slab's far face
        // (49.5 mm) nor a wall's inside.
        EXPECT_GE(p.x(), 10e-3 - 1e-9);
        EXPECT_LE(p.x(), 50e-3 + 1e-9);
        EXPECT_GE(p.z(), 10e-3 - 1e-9);
        EXPECT_LE(p.z(), 50e-3 + 1e-9);
        EXPECT_LE(p.y(), 10e-3 + 1e-9) << "node " << n;
        if (std::abs(p.y() - 4.5e-3) < 1e-9) ++top;
    }
    EXPECT_EQ(top, 8 * 8);  // every top node in the square x, z 10..50 mm: 14.5..49.5 mm
    // A patch that is not a frame, or has no area, is refused naming the field.
    SlidePatch skew = patch;
    skew.v = Eigen::Vector3d(0.0, 0.6, 0.8);
    EXPECT_THROW(
        {
            try {
                skinNodesUnder(*model, skew);
            } catch (const ValueError& e) {
                EXPECT_NE(std::string(e.what()).find("slidePatch"), std::string::npos);
                throw;
            }
        },
        ValueError);
    SlidePatch flat = patch;
    flat.extentV = 0;
    EXPECT_THROW(skinNodesUnder(*model, flat), ValueError);
}

}  // namespace
}  // namespace palp::haptics
