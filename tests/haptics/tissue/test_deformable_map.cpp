// Volume rays through deforming tissue (docs/algorithms.md section 10): DeformableBody's map
// between the rest and the current configuration (exact at the nodes, inverse of itself), and
// AVC's volume rays mapped through it: on the tumour phantom pressed over its inclusion, the
// first-hit ray through the scan finds the inclusion where its embedded mesh (deformed with the
// tissue, an independent path) is, while the unmapped ray finds where it was at rest.
#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <Eigen/LU>
#include <algorithm>
#include <cmath>
#include <iostream>
#include <limits>
#include <random>

#include "alloc_counter.h"
#include "palp/haptics/rendering/coupling.h"
#include "palp/haptics/scene.h"
#include "palp/haptics/tissue/deformable.h"
#include "palp/volume/phantom.h"

namespace palp::haptics {
namespace {

constexpr double kT = 1e-3;

Eigen::Vector3d mm(double x, double y, double z) { return 1e-3 * Eigen::Vector3d(x, y, z); }

// The tumour phantom (a 100 x 50 x 100 mm block, surface y = 0 facing -y, 40 HU tissue under a
// 2 mm fat layer) with its +200 HU inclusion of radius 8 mm centred 12 mm deep (top 4 mm deep),
// at 0.5 mm voxels; voxelised into 5 mm cells of uniform 5 kPa tissue fixed at the bottom, the
// inclusion's icosphere embedded in the elements.
struct TumourPhantom {
    volume::PhantomParams params;
    volume::Volume volume;
    std::shared_ptr<Scene> scene;
    std::shared_ptr<DeformableModel> model;

    explicit TumourPhantom(DeformableSolver solver = DeformableSolver::wholeMeshExplicit) {
        params.scene = volume::PhantomScene::Tumour;
        params.inclusionCentre = mm(0, 12, 0);
        volume::PhantomSpec spec;
        spec.params = params;
        spec.voxelSize = 0.5e-3;
        volume = volume::makePhantomVolume(spec);
        SceneOptions so;
        so.surfaceIso = std::numeric_limits<double>::quiet_NaN();
        scene = Scene::fromVolume(volume, so);
        fem::VoxelizeOptions vo;
        vo.elementSize = 5e-3;
        vo.tissueThreshold = -500;
        fem::ElasticMaterial mat;
        mat.youngsModulus = 5e3;
        mat.poissonRatio = 0.45;
        mat.dampingAlpha = 60;
        DeformableOptions o;
        o.solverKind = solver;
        if (solver == DeformableSolver::asyncRegions) {
            o.regions.threaded = false;
            o.regions.primaryNodes = 30;
            o.regions.lod = 2;
            o.regionsCentre = Eigen::Vector3d::Zero();
        }
        model = DeformableModel::fromVolume(volume, vo, mat, fem::BoxFace::yMax, o);
        model->embedMesh(volume::Phantom(params).inclusionMesh());
        scene->setDeformable(model);
    }
};

// Presses the surface centre with @p newtons (down, +y) for @p ticks ticks.
void press(DeformableBody& body, double newtons, int ticks) {
    body.applyContactForce(mm(0, 0, 0), Eigen::Vector3d(0, newtons, 0));
    for (int i = 0; i < ticks; ++i) ASSERT_EQ(body.step(kT), 0u) << "tick " << i;
}

// The map reproduces the FEM's nodal displacements exactly and restFromCurrent inverts
// currentFromRest inside the tissue, near the contact where the strain is largest too.
TEST(DeformableMap, NodesExactAndInverseOfItself) {
    TumourPhantom ph;
    DeformableBody body(ph.model);
    press(body, 0.1, 600);
    const fem::HexMesh& mesh = ph.model->model().mesh();
    double largest = 0;
    for (int n = 0; n < mesh.nodeCount(); ++n) {
        if (!mesh.nodeActive()[static_cast<std::size_t>(n)]) continue;
        const Eigen::Vector3d x = body.currentFromRest(mesh.nodePosition(n));
        ASSERT_LT((x - body.nodePosition(n)).norm(), 1e-12) << "node " << n;
        largest = std::max(largest, body.displacement().segment<3>(3 * n).norm());
    }
    EXPECT_GT(largest, 1.5e-3);  // a press of millimetres: the map has something to undo
    std::mt19937 rng(7);
    std::uniform_real_distribution<double> lateral(-12e-3, 12e-3), depth(0.2e-3, 30e-3);
    double worst = 0;
    for (int i = 0; i < 500; ++i) {
        const Eigen::Vector3d rest(lateral(rng), depth(rng), lateral(rng));
        const Eigen::Vector3d back = body.restFromCurrent(body.currentFromRest(rest));
        worst = std::max(worst, (back - rest).norm());
    }
    EXPECT_LT(worst, 1e-8);
    // Undisplaced far away and outside the lattice: the nearest lattice point's value.
    EXPECT_LT(body.displacementAtRest(mm(48, 48, 48)).norm(), 1e-5);
    EXPECT_TRUE(body.displacementAtRest(mm(0, -30, 0)).allFinite());
}

// Where the centre ray straight down from the proxy (on the deformed surface over the
// inclusion) finds the inclusion, for a coupling of @p source.
struct RayLengths {
    double mapped, unmapped, mesh;
};

RayLengths centreRays(const Scene& scene, const DeformableBody& body,
                      const Eigen::Vector3d& proxy) {
    CouplingParams p;
    p.mode = CouplingMode::AVC;
    p.bundle.ringCount = 0;
    p.bundle.length = 0.04;
    p.referenceLength = 0.02;
    p.firstHit.threshold = 120;  // between the tissue's 40 HU and the inclusion's 200
    p.source = RaySource::VolumeFirstHit;
    Coupling mapped(scene.volumeView(), nullptr, p), unmapped(scene.volumeView(), nullptr, p);
    mapped.setDeformation(&body);
    CouplingParams pm = p;
    pm.source = RaySource::Mesh;
    pm.hardMask = kernels::kMaskBone;
    Coupling mesh(nullptr, nullptr, pm, &body.surfaces());
    const Eigen::Vector3d probe = proxy + mm(0, 2, 0), zero = Eigen::Vector3d::Zero();
    const Eigen::Vector3d t1 = Eigen::Vector3d::UnitX(), t2 = Eigen::Vector3d::UnitZ();
    CouplingOutput a, b, c;
    mapped.compute(proxy, probe, zero, zero, t1, t2, a);
    unmapped.compute(proxy, probe, zero, zero, t1, t2, b);
    mesh.compute(proxy, probe, zero, zero, t1, t2, c);
    return {a.rayLength, b.rayLength, c.rayLength};
}

TEST(DeformableMap, VolumeRaysFindTheInclusionWhereTheTissueCarriedIt) {
    TumourPhantom ph;
    DeformableBody body(ph.model);
    // At rest the three agree: 4 mm from the surface to the inclusion's top.
    const Eigen::Vector3d restProxy = mm(0, -0.01, 0);
    const RayLengths rest = centreRays(*ph.scene, body, restProxy);
    EXPECT_NEAR(rest.mesh, 4.01e-3, 0.05e-3);
    EXPECT_NEAR(rest.mapped, rest.mesh, 0.3e-3);
    EXPECT_NEAR(rest.unmapped, rest.mesh, 0.3e-3);

    press(body, 0.1, 600);
    const Eigen::Vector3d proxy = body.currentFromRest(Eigen::Vector3d::Zero()) - mm(0, 0.01, 0);
    const double surfaceDown = proxy.y() - restProxy.y();
    const Eigen::Vector3d top = ph.params.inclusionCentre - mm(0, 8, 0);
    const double topDown = body.currentFromRest(top).y() - top.y();
    ASSERT_GT(surfaceDown, 2e-3);
    ASSERT_GT(topDown, 1e-3);  // the press carried the inclusion by a millimetre or more
    const RayLengths now = centreRays(*ph.scene, body, proxy);
    std::cout << "surface " << surfaceDown * 1e3 << " mm, inclusion top " << topDown * 1e3
              << " mm down; centre ray mapped " << now.mapped * 1e3 << " mm, unmapped "
              << now.unmapped * 1e3 << " mm, embedded mesh " << now.mesh * 1e3 << " mm\n";
    // The embedded mesh is the inclusion deformed with the tissue: the mapped volume ray
    // agrees with it to the scan's partial-volume edge; the unmapped ray misses the motion of
    // the inclusion (it sees the rest scan under the moved surface).
    EXPECT_NEAR(now.mapped, now.mesh, 0.3e-3);
    EXPECT_GT(std::abs(now.unmapped - now.mesh), 0.8 * topDown);
}

// The material frame at the contact: anchorRotation() is a proper rotation that takes the rest
// normal to within a few degrees of the current normal of the triangle the proxy is anchored on
// (found here independently from the rest surface and the nodes' positions; the frame blends
// the vertices' rotations, so it follows the smooth surface rather than the facet), turns as
// the anchor slides continuously across the facets' edges (a per-facet frame jumped there by
// the facets' relative tilt), and turns a coupling's rays so that a probe pressed along the
// frame's normal casts them along the rest normal.
TEST(DeformableMap, AnchorRotationIsTheContactsMaterialFrame) {
    TumourPhantom ph;
    DeformableBody body(ph.model);
    press(body, 0.1, 600);
    // A point on the dimple's slope, 6 mm from the press.
    const Eigen::Vector3d rest = mm(6, 0, 2);
    const Eigen::Vector3d x = body.currentFromRest(rest);
    const Eigen::Vector3d out(0, -1, 0);  // the rest surface's outward normal
    ASSERT_TRUE(body.anchor(x + 0.5e-3 * out, out));
    const Eigen::Matrix3d R = body.anchorRotation();
    EXPECT_LT((R.transpose() * R - Eigen::Matrix3d::Identity()).norm(), 1e-12);
    EXPECT_NEAR(R.determinant(), 1.0, 1e-12);

    // The top-face (y = 0) triangle under a rest point: its current outward normal, and the
    // smooth normal there (its vertices' area-weighted normals blended with the point's
    // barycentric weights), found from the rest surface and the nodes' positions.
    const DeformableModel& model = *ph.model;
    const fem::SurfaceMesh& surface = model.surface();
    const auto current = [&](std::uint32_t v) { return body.nodePosition(surface.vertexNode[v]); };
    const auto vertexNormal = [&](std::uint32_t v) {
        Eigen::Vector3d n = Eigen::Vector3d::Zero();
        for (const auto& t : surface.triangles)
            if (t[0] == v || t[1] == v || t[2] == v)
                n += (current(t[1]) - current(t[0])).cross(current(t[2]) - current(t[0]));
        return n;
    };
    struct Normals {
        Eigen::Vector3d facet = Eigen::Vector3d::Zero(), smooth = Eigen::Vector3d::Zero();
    };
    const auto normalsUnder = [&](const Eigen::Vector3d& at) {
        Normals found;
        for (const auto& t : surface.triangles) {
            std::array<Eigen::Vector3d, 3> r;
            bool top = true;
            for (std::size_t k = 0; k < 3; ++k) {
                r[k] = surface.vertices[t[k]].cast<double>();
                top = top && std::abs(r[k].y()) < 1e-9;
            }
            if (!top) continue;
            // Barycentric coordinates in the x-z plane.
            const Eigen::Vector2d a(r[0].x(), r[0].z()), b(r[1].x(), r[1].z()),
                cc(r[2].x(), r[2].z());
            const Eigen::Vector2d p(at.x(), at.z());
            const double det = (b - a).x() * (cc - a).y() - (b - a).y() * (cc - a).x();
            const double u = ((p - a).x() * (cc - a).y() - (p - a).y() * (cc - a).x()) / det;
            const double v = ((b - a).x() * (p - a).y() - (b - a).y() * (p - a).x()) / det;
            if (u < -1e-9 || v < -1e-9 || u + v > 1 + 1e-9) continue;
            found.facet = (current(t[1]) - current(t[0])).cross(current(t[2]) - current(t[0]));
            found.facet.normalize();
            found.smooth =
                ((1 - u - v) * vertexNormal(t[0]).normalized() +
                 u * vertexNormal(t[1]).normalized() + v * vertexNormal(t[2]).normalized())
                    .normalized();
            if (found.facet.dot(out) < 0) found.facet = -found.facet;
            if (found.smooth.dot(out) < 0) found.smooth = -found.smooth;
            break;
        }
        return found;
    };
    const auto degrees = [](const Eigen::Vector3d& a, const Eigen::Vector3d& b) {
        return std::acos(std::clamp(a.normalized().dot(b.normalized()), -1.0, 1.0)) * 180 /
               3.14159265358979;
    };
    const Normals here = normalsUnder(rest);
    ASSERT_GT(here.facet.norm(), 0.5) << "no top triangle under the point";
    const double tilt = degrees(here.smooth, out);
    std::cout << "under the slope point: the surface tilted " << tilt << " degrees (the facet "
              << degrees(here.facet, out) << "), the frame " << degrees(R * out, out)
              << " degrees, " << degrees(R * out, here.smooth) << " from the surface's normal\n";
    EXPECT_GT(tilt, 2.0);  // a slope for the frame to undo
    EXPECT_LT(degrees(R * out, here.smooth), 0.25 * tilt);

    // Continuity: along a line of anchors across the slope's facets (0.1 mm apart in rest x),
    // R turns by a small fraction of the jumps of the facets' normals under them (a frame per
    // facet turned by those jumps).
    double worst = 0, facetJump = 0;
    Eigen::Matrix3d last = R;
    Eigen::Vector3d lastFacet = here.facet;
    for (int i = 1; i <= 60; ++i) {
        const Eigen::Vector3d at = rest + mm(0.1 * i, 0, 0);
        const Eigen::Vector3d y = body.currentFromRest(at);
        ASSERT_TRUE(body.anchor(y + 0.5e-3 * out, out));
        const Eigen::Matrix3d Ri = body.anchorRotation();
        const Eigen::AngleAxisd turn(Ri * last.transpose());
        worst = std::max(worst, std::abs(turn.angle()) * 180 / 3.14159265358979);
        last = Ri;
        const Eigen::Vector3d facet = normalsUnder(at).facet;
        facetJump = std::max(facetJump, degrees(facet, lastFacet));
        lastFacet = facet;
    }
    std::cout << "between anchors 0.1 mm apart the frame turns at most " << worst
              << " degrees, the facet under them " << facetJump << " degrees\n";
    EXPECT_GT(facetJump, 1.0);
    EXPECT_LT(worst, 0.2 * facetJump);
    ASSERT_TRUE(body.anchor(x + 0.5e-3 * out, out));

    // A probe pressed along the frame's normal: rays along the rest normal.
    const Eigen::Vector3d nFrame = R * out;
    CouplingParams p;
    p.mode = CouplingMode::AVC;
    p.source = RaySource::VolumeFirstHit;
    p.firstHit.threshold = 120;
    Coupling framed(ph.scene->volumeView(), nullptr, p), plain(ph.scene->volumeView(), nullptr, p);
    framed.setMaterialFrame(R);
    const Eigen::Vector3d probe = x - 2e-3 * nFrame, zero = Eigen::Vector3d::Zero();
    const Eigen::Vector3d t1 = nFrame.cross(Eigen::Vector3d::UnitZ()).normalized();
    const Eigen::Vector3d t2 = nFrame.cross(t1);
    CouplingOutput a, b;
    framed.compute(x, probe, zero, zero, t1, t2, a);
    plain.compute(x, probe, zero, zero, t1, t2, b);
    const auto dir = [](const kernels::RayBundle& bu) {
        return Eigen::Vector3d(bu.dx[0], bu.dy[0], bu.dz[0]);
    };
    EXPECT_LT((dir(framed.bundle()) + out).norm(), 1e-6);
    EXPECT_LT((dir(plain.bundle()) + nFrame).norm(), 1e-6);
    // The force itself stays along the world's proxy->probe direction.
    EXPECT_LT(a.force.normalized().cross(nFrame).norm(), 1e-9);

    body.clearForce();
    EXPECT_TRUE(body.anchorRotation().isIdentity(0.0));
}

// A tick of a mapped coupling allocates nothing and stays bounded.
TEST(DeformableMap, MappedTicksAllocateNothing) {
    TumourPhantom ph;
    DeformableBody body(ph.model);
    press(body, 0.3, 200);
    CouplingParams p;
    p.mode = CouplingMode::AVCEC;
    p.source = RaySource::VolumeFirstHit;
    p.firstHit.threshold = 120;
    Coupling c(ph.scene->volumeView(), nullptr, p);
    c.setDeformation(&body);
    const Eigen::Vector3d proxy = body.currentFromRest(Eigen::Vector3d::Zero()) - mm(0, 0.01, 0);
    const Eigen::Vector3d zero = Eigen::Vector3d::Zero();
    CouplingOutput out;
    c.compute(proxy, proxy + mm(1, 2, 0), zero, zero, Eigen::Vector3d::UnitX(),
              Eigen::Vector3d::UnitZ(), out);
    const std::uint64_t before = test::allocationCount();
    for (int i = 0; i < 50; ++i) {
        c.compute(proxy, proxy + mm(0.02 * i, 2, 0), zero, zero, Eigen::Vector3d::UnitX(),
                  Eigen::Vector3d::UnitZ(), out);
        ASSERT_TRUE(out.force.allFinite());
        ASSERT_EQ(out.rays, 17);
    }
    EXPECT_EQ(test::allocationCount() - before, 0u);
}

}  // namespace
}  // namespace palp::haptics
