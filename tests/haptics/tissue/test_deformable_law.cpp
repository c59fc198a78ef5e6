// A deformable body of neo-Hookean tissue (DeformableSetup::material.law): pressed, its surface
// dents where the rays see it and an embedded inclusion moves with it, as on linear tissue, and
// the nonlinear law, stiffer in compression, dents less under the same load; the automatic
// solver choice follows the element budget for it and says why, and the regions run it.

#include <gtest/gtest.h>

#include <string>

#include "deformable_fixtures.h"
#include "palp/haptics/tissue/deformable_setup.h"
#include "palp/volume/phantom.h"

namespace palp::haptics {
namespace {

using dfix::mm;
using fixtures::kT;

std::shared_ptr<DeformableModel> cubeOf(fem::MaterialLaw law, bool inclusion) {
    fem::ElasticMaterial m = dfix::softTissue();
    m.law = law;
    auto model = DeformableModel::box(Eigen::Vector3d::Constant(0.04), {9, 9, 9}, m,
                                      fem::BoxFace::yMax, {}, mm(-20, 0, -20));
    if (inclusion)
        model->embedMesh(volume::icosphere(volume::PhantomSphere{mm(0, 12, 0), 6e-3}, 2));
    return model;
}

/// Where a ray down the press axis through (0, -10, 0) mm meets @p body's @p mask, y (m).
double rayHitY(const DeformableBody& body, unsigned mask) {
    kernels::MeshHit hit;
    kernels::intersectOne(body.surfaces(), mm(0, -10, 0), Eigen::Vector3d(0, 1, 0), 0.0f, 0.1f,
                          mask, hit);
    EXPECT_NE(hit.geomId, kernels::kNoGeometry);
    return -10e-3 + hit.t;
}

// The same 0.2 N press on linear and on neo-Hookean tissue, held until still: the surface the
// proxy's and AVC/AVCEC's rays meet is dented by the top-centre node's displacement (the ray
// runs through that node), the inclusion embedded in the tissue has moved with it, and the
// neo-Hookean tissue, stiffer in compression, dents less.
TEST(DeformableLaw, ANeoHookeanPressDentsTheSurfaceTheRaysSee) {
    double dent[2] = {0, 0};
    for (const fem::MaterialLaw law : {fem::MaterialLaw::linear, fem::MaterialLaw::neoHookean}) {
        const bool neo = law == fem::MaterialLaw::neoHookean;
        SCOPED_TRACE(neo ? "neo-Hookean" : "linear");
        auto model = cubeOf(law, true);
        DeformableBody body(model);
        EXPECT_EQ(body.model().model().material().law, law);
        const double restSurface = rayHitY(body, kernels::kMaskSurface);
        const double restInclusion = rayHitY(body, kernels::kMaskBone);
        EXPECT_NEAR(restSurface, 0, 1e-7);
        for (int i = 0; i < 1500; ++i) {
            body.applyContactForce(mm(0, 0, 0), Eigen::Vector3d(0, 0.2, 0));
            ASSERT_EQ(body.step(kT), 0u) << "tick " << i;
        }
        const int node = dfix::topCentreNode(*model);
        const double uy = body.displacement()[3 * node + 1];
        const double surface = rayHitY(body, kernels::kMaskSurface);
        EXPECT_GT(uy, 1e-3);  // millimetres
        EXPECT_NEAR(surface - restSurface, uy, 1e-6);
        // The inclusion's top moved down with the tissue, less than the surface.
        const double moved = rayHitY(body, kernels::kMaskBone) - restInclusion;
        EXPECT_GT(moved, 0.2e-3);
        EXPECT_LT(moved, uy);
        dent[neo ? 1 : 0] = uy;
    }
    std::printf("dent under 0.2 N: linear %.3f mm, neo-Hookean %.3f mm\n", dent[0] * 1e3,
                dent[1] * 1e3);
    EXPECT_LT(dent[1], dent[0]);
}

volume::Volume bonePhantom() {
    volume::PhantomSpec spec;
    spec.params.scene = volume::PhantomScene::Bone;
    spec.voxelSize = 2e-3;
    return volume::makePhantomVolume(spec);
}

// The automatic choice treats neo-Hookean tissue as linear tissue's budget decides: the whole
// mesh (TLED) within it (the bone phantom at 5 mm), the regions with a TLED primary and a linear
// far field over it (at 2.5 mm), and says which; the regions asked for take it too.
TEST(DeformableLaw, AutoChoosesBySizeForNeoHookeanAndTheRegionsRunItInThePrimary) {
    const volume::Volume vol = bonePhantom();
    DeformableSetup setup;
    setup.supportFace = fem::BoxFace::yMax;
    setup.autoSolver = true;
    setup.material.law = fem::MaterialLaw::neoHookean;
    SolverChoice choice;
    auto model = makeDeformableModel(vol, setup, &choice);
    EXPECT_EQ(model->options().solverKind, DeformableSolver::wholeMeshExplicit);
    EXPECT_EQ(choice.solver, DeformableSolver::wholeMeshExplicit);
    EXPECT_NE(choice.reason.find("within 8000 (neo-Hookean: TLED)"), std::string::npos)
        << choice.reason;

    setup.voxelize.elementSize = 2.5e-3;
    model = makeDeformableModel(vol, setup, &choice);
    EXPECT_EQ(model->options().solverKind, DeformableSolver::asyncRegions);
    EXPECT_NE(choice.reason.find("over 8000 (neo-Hookean: TLED in the primary, linear far field)"),
              std::string::npos)
        << choice.reason;

    setup.voxelize.elementSize = 5e-3;
    setup.autoSolver = false;
    setup.options.solverKind = DeformableSolver::asyncRegions;
    model = makeDeformableModel(vol, setup, &choice);
    EXPECT_EQ(model->options().solverKind, DeformableSolver::asyncRegions);
    EXPECT_EQ(choice.reason, "regions: asked");
}

}  // namespace
}  // namespace palp::haptics
