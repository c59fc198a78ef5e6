// Deformable scenes refuse what they cannot run, naming the field: AVC without data, bad
// options, the hanging values of issue 20, options out of bounds, tissue too stiff for the
// explicit substeps.
#include <gtest/gtest.h>

#include <array>
#include <chrono>
#include <cmath>
#include <iostream>
#include <limits>
#include <random>
#include <string>
#include <thread>
#include <vector>

#include "alloc_counter.h"
#include "deformable_fixtures.h"
#include "palp/base/error.h"
#include "palp/fem/implicit_solver.h"
#include "palp/haptics/session.h"
#include "palp/haptics/tissue/deformable.h"
#include "palp/kernels/embree_scene.h"
#include "palp/volume/phantom.h"
#include "session_fixtures.h"

namespace palp::haptics {
namespace {

using namespace dfix;

TEST(DeformableSession, RefusesAvcWithoutDataAndBadOptions) {
    auto scene = deformableScene(cube(3e-3));
    PathDevice device({{0.0, mm(0, -5, 0)}});
    SessionParams p = vcParams();
    // AVC needs something to cast against: neither hard meshes, an embedded mesh nor a volume.
    p.coupling.mode = CouplingMode::AVC;
    p.coupling.source = RaySource::Mesh;
    EXPECT_THROW(Session(scene, device, p), ValueError);
    p.coupling.source = RaySource::VolumeFirstHit;
    EXPECT_THROW(Session(scene, device, p), ValueError);
    Session ok(scene, device, vcParams());
    Command c;
    c.kind = Command::Kind::SetCoupling;
    c.coupling = vcParams().coupling;
    c.coupling.mode = CouplingMode::AVCEC;
    EXPECT_THROW(ok.send(c), ValueError);
    DeformableOptions o;
    o.filterWidth = -1e-3;
    EXPECT_THROW(validateDeformableOptions(o), ValueError);
    o = {};
    o.filterCutoff = 0.5;
    EXPECT_THROW(validateDeformableOptions(o), ValueError);
    EXPECT_THROW(DeformableBody(nullptr), ValueError);
}

/// The message of the ValueError @p f throws ("" when none).
template <typename F>
std::string refusal(F&& f) {
    try {
        f();
    } catch (const ValueError& e) {
        return e.what();
    }
    return "";
}

// Issue 20: `palp palpate --phantom bone --deformable --young-kpa 1e300` (or --fem-damping,
// --fem-beta 1e20) did not finish 0.1 s: the whole-mesh explicit solver ran its 4096-substep cap
// every tick (and beta 1e20 made the critical step 0). Through the library the same values are
// refused at set-up, before the scene is voxelised, naming the field.
TEST(DeformableModel, HangingValuesOfIssue20AreRefusedAtSetUpNamingTheField) {
    volume::PhantomSpec spec;
    spec.params.scene = volume::PhantomScene::Bone;
    spec.voxelSize = 2e-3;
    const volume::Volume vol = volume::makePhantomVolume(spec);
    fem::VoxelizeOptions vo;
    vo.boneThreshold = 500;
    const auto build = [&](const fem::ElasticMaterial& m, const fem::VoxelizeOptions& v,
                           const DeformableOptions& o = {}) {
        return refusal([&] { DeformableModel::fromVolume(vol, v, m, fem::BoxFace::yMax, o); });
    };
    fem::ElasticMaterial m = softTissue();
    m.youngsModulus = 1e303;  // --young-kpa 1e300
    EXPECT_EQ(build(m, vo),
              "material youngsModulus: expected a value in [1, 1e+12] Pa, found 1e+303");
    m = softTissue();
    m.dampingAlpha = 1e20;  // --fem-damping 1e20
    EXPECT_EQ(build(m, vo),
              "material dampingAlpha: expected a value in [0, 10000] 1/s, found 1e+20");
    m = softTissue();
    m.dampingBeta = 1e20;  // --fem-beta 1e20
    EXPECT_EQ(build(m, vo), "material dampingBeta: expected a value in [0, 1] s, found 1e+20");
    m = softTissue();
    m.poissonRatio = 0.5;  // --poisson 0.5
    EXPECT_EQ(build(m, vo), "material poissonRatio: expected a value in (-1, 0.5), found 0.5");
    fem::VoxelizeOptions v = vo;
    v.elementSize = 1e297;  // --fem-cell-mm 1e300
    EXPECT_EQ(build(softTissue(), v),
              "voxelize elementSize: expected a value in [1e-06, 0.1] m, found 1e+297");
    v = vo;
    v.boneThreshold = std::nan("");  // --bone-hu nan
    EXPECT_EQ(build(softTissue(), v),
              "voxelize boneThreshold: expected a value in [-1e+09, 1e+09], found nan");
    v = vo;
    v.tissueThreshold = 1e300;  // --tissue-hu 1e300
    EXPECT_EQ(build(softTissue(), v),
              "voxelize tissueThreshold: expected a value in [-1e+09, 1e+09], found 1e+300");
    DeformableOptions o;
    o.filterWidth = 1e297;  // --filter-mm 1e300
    EXPECT_EQ(build(softTissue(), vo, o),
              "deformable filterWidth: expected a value in [0, 10] m, found 1e+297");
    // In range but too stiff for the 1 ms tick: 1 TPa bone-phantom tissue on 5 mm cells needs
    // ~2e4 explicit substeps per tick (> solver.maxSubsteps 4096).
    m = softTissue();
    m.youngsModulus = 1e12;
    const std::string stiff = build(m, vo);
    std::cout << "[ issue 20 ] " << stiff << "\n";
    EXPECT_EQ(stiff.rfind("material youngsModulus: expected at most ", 0), 0u) << stiff;
    EXPECT_NE(stiff.find("in the 0.001 s tick with 5 mm cells"), std::string::npos) << stiff;
    EXPECT_NE(stiff.find("found 1e+12 Pa ("), std::string::npos) << stiff;
    EXPECT_NE(stiff.find("or raise deformable solver.maxSubsteps"), std::string::npos) << stiff;
    // Beta in range but too much for the tick on 5 kPa.
    m = softTissue();
    m.dampingBeta = 1.0;
    o = {};
    o.solver.maxSubsteps = 1024;
    const std::string damped = build(m, vo, o);
    std::cout << "[ issue 20 ] " << damped << "\n";
    EXPECT_EQ(damped.rfind("material dampingBeta: expected at most ", 0), 0u) << damped;
    EXPECT_NE(damped.find("found 1 s ("), std::string::npos) << damped;
}

TEST(DeformableModel, OptionsOutOfBoundsAreRefusedNamingTheField) {
    const auto check = [](const DeformableOptions& o) {
        return refusal([&] { validateDeformableOptions(o); });
    };
    DeformableOptions o;
    EXPECT_EQ(check(o), "");
    o.filterWidth = std::nan("");
    EXPECT_EQ(check(o), "deformable filterWidth: expected a value in [0, 10] m, found nan");
    o = {};
    o.filterCutoff = HUGE_VAL;
    EXPECT_NE(check(o).find("deformable filterCutoff"), std::string::npos);
    o = {};
    o.tickSeconds = 0;
    EXPECT_EQ(check(o), "deformable tickSeconds: expected a value in [1e-05, 0.1] s, found 0");
    o = {};
    o.solver.maxSubsteps = 1'000'000'000;
    EXPECT_EQ(check(o),
              "deformable solver.maxSubsteps: expected a count in [1, 65536], found 1000000000");
    o = {};
    o.solver.safetyFactor = std::nan("");
    EXPECT_EQ(check(o), "deformable solver.safetyFactor: expected a value in (0, 1], found nan");
    o = {};
    o.regionsCentre = Eigen::Vector3d(0, 1e300, 0);
    EXPECT_NE(check(o).find("deformable regionsCentre"), std::string::npos);
    o = {};
    o.solverKind = DeformableSolver::asyncRegions;
    o.regions.tickSeconds = 1e300;
    EXPECT_EQ(check(o),
              "deformable regions.tickSeconds: expected a value in [1e-05, 0.1] s, found 1e+300");
    o.regions.tickSeconds = 1e-3;
    o.regions.maxSubsteps = 0;
    EXPECT_EQ(check(o), "deformable regions.maxSubsteps: expected a count in [1, 65536], found 0");
}

// A stiff but valid tissue: 1 GPa on 5 mm cells needs ~700 substeps per 1 ms tick. With the
// default 64 substeps per tick (whole mesh or regions) it is refused at set-up with the substep
// message; a caller who allows 1024 gets it run, every tick the full tick of stable substeps.
TEST(DeformableModel, StiffTissueRunsBoundedOrIsRefusedWithTheSubstepMessage) {
    fem::ElasticMaterial m = softTissue();
    m.youngsModulus = 1e9;
    const std::string whole = refusal([&] {
        DeformableModel::box(Eigen::Vector3d::Constant(0.04), {9, 9, 9}, m, fem::BoxFace::yMax, {},
                             mm(-20, 0, -20));
    });
    EXPECT_EQ(whole.rfind("material youngsModulus: expected at most 8.29e+06 Pa", 0), 0u) << whole;
    EXPECT_NE(whole.find("found 1e+09 Pa (703 substeps per tick)"), std::string::npos) << whole;
    DeformableOptions allow;
    allow.solver.maxSubsteps = 1024;
    const auto model = DeformableModel::box(Eigen::Vector3d::Constant(0.04), {9, 9, 9}, m,
                                            fem::BoxFace::yMax, allow, mm(-20, 0, -20));
    DeformableBody body(model);
    const double need = fem::explicitSubstepsPerTick(model->model(), 0.9, kT);
    EXPECT_EQ(need, 703);
    body.applyContactForce(Eigen::Vector3d::Zero(), Eigen::Vector3d(0, 1.0, 0));
    for (int i = 0; i < 10; ++i) {
        ASSERT_EQ(body.step(kT), 0u) << "tick " << i;
        ASSERT_EQ(body.lastSubsteps(), static_cast<int>(need));
    }
    // 1 N on a 1 GPa, 40 mm cube: micrometres at most, and finite.
    EXPECT_TRUE(body.displacement().allFinite());
    EXPECT_GT(body.maxSurfaceDisplacement(), 0.0);
    EXPECT_LT(body.maxSurfaceDisplacement(), 1e-5);

    DeformableOptions o;
    o.solverKind = DeformableSolver::asyncRegions;
    o.regions.threaded = false;
    const std::string r = refusal([&] {
        DeformableModel::box(Eigen::Vector3d::Constant(0.04), {9, 9, 9}, m, fem::BoxFace::yMax, o,
                             mm(-20, 0, -20));
    });
    std::cout << "[ issue 20 ] " << r << "\n";
    EXPECT_EQ(r.rfind("material youngsModulus: expected at most ", 0), 0u) << r;
    EXPECT_NE(r.find("or raise deformable regions.maxSubsteps"), std::string::npos) << r;
}

}  // namespace
}  // namespace palp::haptics
