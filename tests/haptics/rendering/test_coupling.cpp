// VC / AVC / AVCEC coupling (docs/algorithms.md sections 1-3): exact forces, ray lengths against
// analytic planes (mesh and volume sources), the AVCEC derivatives against analytic angular and
// surface gradients, the closed-loop energy test on the AVC phantom, allocation-free ticks and
// parameter validation.
//
// Frame of every test: the palpated surface at y = 0, depth along +y (as the phantoms), tangents
// t1 = x, t2 = z.

#include <gtest/gtest.h>

#include <array>
#include <cmath>
#include <cstdio>
#include <functional>
#include <limits>
#include <memory>
#include <numbers>
#include <string>
#include <vector>

#include "alloc_counter.h"
#include "coupling_test_scene.h"
#include "palp/base/error.h"
#include "palp/haptics/rendering/coupling.h"
#include "palp/kernels/triangle_mesh.h"
#include "palp/volume/phantom.h"
#include "ray_test_shapes.h"

namespace {

using namespace palp::haptics;
using palp::kernels::TriangleMesh;
using palp::test::kT1;
using palp::test::kT2;
using palp::test::kVoxel;
using palp::test::kZero;
using palp::test::MeshScene;
using palp::test::sceneParams;
using Vec = Eigen::Vector3d;

/// The stiffness the spec gives for a ray of length @p L.
double expectedStiffness(const CouplingParams& p, double L) {
    return std::min(p.baseStiffness * std::clamp(p.referenceLength / L, 1.0, p.maxMultiplier),
                    p.maxStiffness);
}

void addVertex(TriangleMesh& m, const Vec& v) {
    for (int a = 0; a < 3; ++a) m.positions.push_back(static_cast<float>(v[a]));
}

/// Quad (two triangles) with corners @p a, @p b, @p c, @p d in order.
TriangleMesh quadMesh(const Vec& a, const Vec& b, const Vec& c, const Vec& d) {
    TriangleMesh m;
    for (const Vec& v : {a, b, c, d}) addVertex(m, v);
    m.indices = {0, 1, 2, 0, 2, 3};
    return m;
}

/// Square of half-size @p s in the plane through @p c with unit normal @p n.
TriangleMesh planeMesh(const Vec& n, const Vec& c, double s) {
    Vec u, v;
    palp::kernels::orthonormalBasis(n, u, v);
    return quadMesh(c - s * u - s * v, c + s * u - s * v, c + s * u + s * v, c - s * u + s * v);
}

// ---------------------------------------------------------------------------------------------
// 1. VC

TEST(Coupling, VcForceIsMinusKDd) {
    CouplingParams p = sceneParams(CouplingMode::VC, RaySource::VolumeFirstHit);
    p.baseStiffness = 350;
    Coupling c(nullptr, nullptr, p);  // VC needs no data
    EXPECT_FALSE(c.sourceAvailable());
    const Vec proxy(1e-3, -2e-3, 0.5e-3);
    const Vec probe = proxy + Vec(1.5e-3, 2.5e-3, -0.7e-3);
    CouplingOutput out;
    c.compute(proxy, probe, kZero, kZero, kT1, kT2, out);
    const Vec x = probe - proxy;
    EXPECT_NEAR((out.force + 350 * x).norm(), 0, 1e-15);
    EXPECT_DOUBLE_EQ(out.stiffness, 350);
    EXPECT_DOUBLE_EQ(out.distance, x.norm());
    EXPECT_DOUBLE_EQ(out.energy, 0.5 * 350 * x.squaredNorm());
    EXPECT_EQ(out.rays, 0);
    EXPECT_EQ(out.proxyForce, kZero);
    EXPECT_EQ(out.energyForce, kZero);
    EXPECT_EQ(c.bundle().count, 0);
}

TEST(Coupling, VcDampingActsOnTheRelativeVelocity) {
    CouplingParams p = sceneParams(CouplingMode::VC, RaySource::VolumeFirstHit);
    p.damping = 2.5;
    Coupling c(nullptr, nullptr, p);
    const Vec proxy(0, 0, 0), probe(0, 3e-3, 0);
    const Vec vpy(0.01, 0, 0), vpb(-0.02, 0.05, 0.1);
    CouplingOutput out;
    c.compute(proxy, probe, vpy, vpb, kT1, kT2, out);
    const Vec expected = -300 * (probe - proxy) + 2.5 * (vpy - vpb);
    EXPECT_NEAR((out.force - expected).norm(), 0, 1e-14);
    // The damping force opposes the probe's motion relative to the proxy.
    c.compute(proxy, probe, kZero, Vec(0, 0, 0.1), kT1, kT2, out);
    EXPECT_DOUBLE_EQ(out.force.z(), -0.25);
}

TEST(Coupling, BelowMinDistanceOrNonFiniteGivesZero) {
    CouplingParams p = sceneParams(CouplingMode::VC, RaySource::VolumeFirstHit);
    p.damping = 1;
    p.minDistance = 1e-6;
    Coupling c(nullptr, nullptr, p);
    const Vec proxy(1e-3, 0, 0);
    const double nan = std::numeric_limits<double>::quiet_NaN();
    const double inf = std::numeric_limits<double>::infinity();
    CouplingOutput out;
    auto expectZero = [&](const char* what) {
        EXPECT_EQ(out.force, kZero) << what;
        EXPECT_EQ(out.stiffness, 0) << what;
        EXPECT_EQ(out.energy, 0) << what;
        EXPECT_EQ(out.distance, 0) << what;
        EXPECT_EQ(out.rays, 0) << what;
    };
    // D = 0.9 um < eps, even with a velocity difference (no force at all below eps).
    c.compute(proxy, proxy + Vec(0.9e-6, 0, 0), Vec(1, 0, 0), kZero, kT1, kT2, out);
    expectZero("D < eps");
    c.compute(proxy, proxy + Vec(1.1e-6, 0, 0), kZero, kZero, kT1, kT2, out);
    EXPECT_NEAR(out.force.x(), -300 * 1.1e-6, 1e-15);  // just above eps: a force
    c.compute(proxy, Vec(nan, 0, 0), kZero, kZero, kT1, kT2, out);
    expectZero("NaN probe");
    c.compute(Vec(0, inf, 0), proxy, kZero, kZero, kT1, kT2, out);
    expectZero("infinite proxy");
    c.compute(proxy, Vec(0, 1e-3, 0), kZero, Vec(0, nan, 0), kT1, kT2, out);
    expectZero("NaN velocity");
    c.compute(proxy, Vec(0, 1e-3, 0), kZero, kZero, Vec(nan, 0, 0), kT2, out);
    expectZero("NaN tangent");
}

TEST(Coupling, StiffnessMultiplierClamps) {
    const CouplingParams p = sceneParams(CouplingMode::AVC, RaySource::Mesh);
    EXPECT_DOUBLE_EQ(stiffnessMultiplier(p, 10e-3), 3);
    EXPECT_DOUBLE_EQ(stiffnessMultiplier(p, 30e-3), 1);
    EXPECT_DOUBLE_EQ(stiffnessMultiplier(p, 100e-3), 1);
    EXPECT_DOUBLE_EQ(stiffnessMultiplier(p, 1e-3), 8);
    EXPECT_DOUBLE_EQ(stiffnessMultiplier(p, 0), 8);
    EXPECT_DOUBLE_EQ(stiffnessMultiplier(p, -1), 8);
    EXPECT_DOUBLE_EQ(stiffnessMultiplier(p, std::numeric_limits<double>::infinity()), 1);
}

// ---------------------------------------------------------------------------------------------
// 2. AVC ray length and stiffness against a plane at a known depth

TEST(Coupling, AvcMeshPlaneLengthAndStiffnessExact) {
    const double depth = 12e-3;  // hard plane y = 12 mm, facing the proxy
    MeshScene ms(planeMesh(-Vec::UnitY(), Vec(0, depth, 0), 0.1));
    CouplingParams p = sceneParams(CouplingMode::AVC, RaySource::Mesh);
    p.maxStiffness = 1500;  // below k_s m_max = 2400, so that both clamps show
    Coupling c(nullptr, &ms.scene, p);
    ASSERT_TRUE(c.sourceAvailable());
    const double D = 2e-3;
    // L = 10 mm (m = 3), 4 mm (m = 7.5 -> k clamped to k_max), 2 mm (m clamped to 8, then k_max),
    // 35 mm (m clamped to 1).
    for (double L : {10e-3, 4e-3, 2e-3, 35e-3}) {
        const Vec proxy(0.37e-3, depth - L, -0.21e-3);
        const Vec probe = proxy + Vec(0, D, 0);  // pressing along the plane's normal
        CouplingOutput out;
        c.compute(proxy, probe, kZero, kZero, kT1, kT2, out);
        EXPECT_NEAR(out.rayLength, L, 1e-6) << L;
        const double k = expectedStiffness(p, L);
        EXPECT_DOUBLE_EQ(out.stiffness, expectedStiffness(p, out.rayLength)) << L;
        EXPECT_NEAR(out.stiffness, k, 1e-6 * k) << L;
        // The clamps: 4 mm and 2 mm give exactly k_max, 35 mm exactly k_s.
        if (L <= 4e-3) {
            EXPECT_EQ(out.stiffness, p.maxStiffness) << L;
        }
        if (L > p.referenceLength) {
            EXPECT_EQ(out.stiffness, p.baseStiffness) << L;
        }
        EXPECT_NEAR((out.force - (-out.stiffness * D * Vec::UnitY())).norm(), 0, 1e-12) << L;
        EXPECT_NEAR(out.energy, 0.5 * out.stiffness * D * D, 1e-12 * out.energy);
        EXPECT_EQ(out.rays, 1);  // AVC without ring: the centre ray only
        EXPECT_EQ(out.proxyForce, kZero);
        EXPECT_EQ(out.energyForce, kZero);
    }
    // Nothing within L_max: L = L_max, k = k_s.
    CouplingOutput out;
    c.compute(Vec(0, depth - 45e-3, 0), Vec(0, depth - 43e-3, 0), kZero, kZero, kT1, kT2, out);
    EXPECT_NEAR(out.rayLength, p.bundle.length, 1e-9);
    EXPECT_DOUBLE_EQ(out.stiffness, 300);
    // Pulling away from the plane (d = -y): no hit either.
    c.compute(Vec(0, 0, 0), Vec(0, -2e-3, 0), kZero, kZero, kT1, kT2, out);
    EXPECT_DOUBLE_EQ(out.stiffness, 300);
}

TEST(Coupling, AvcRingLowPassIsTheGaussianWeightedMean) {
    const double depth = 10e-3;
    MeshScene ms(planeMesh(-Vec::UnitY(), Vec(0, depth, 0), 0.1));
    CouplingParams p = sceneParams(CouplingMode::AVC, RaySource::Mesh);
    p.bundle.ringCount = 6;
    p.bundle.ringHalfAngle = 0.3;
    p.bundle.ringWeightSigma = 0.2;
    Coupling c(nullptr, &ms.scene, p);
    CouplingOutput out;
    c.compute(Vec(0, 0, 0), Vec(0, 3e-3, 0), kZero, kZero, kT1, kT2, out);
    EXPECT_EQ(out.rays, 7);
    // Ring rays at alpha from the normal hit at L / cos(alpha).
    const double w = std::exp(-0.09 / (2 * 0.04));
    const double k =
        (expectedStiffness(p, depth) + 6 * w * expectedStiffness(p, depth / std::cos(0.3))) /
        (1 + 6 * w);
    EXPECT_NEAR(out.stiffness, k, 1e-5 * k);
    EXPECT_NEAR(out.rayLength, depth, 1e-6);  // the centre ray's L
    // AVCEC traces the stencils as well: 1 + 6 + 8 + 8.
    p.mode = CouplingMode::AVCEC;
    c.setParams(p);
    c.compute(Vec(0, 0, 0), Vec(0, 3e-3, 0), kZero, kZero, kT1, kT2, out);
    EXPECT_EQ(out.rays, 23);
    EXPECT_EQ(c.bundle().count, 23);
}

TEST(Coupling, AvcVolumePlaneFirstHitAndAccumulate) {
    const double depth = 7.3e-3;
    // Hard below y = depth: outward normal -y, inside where -y < -depth.
    const palp::test::Plane plane{-Vec::UnitY(), -depth};
    auto grid = palp::test::shapeVolume([&](const Vec& x) { return plane.sdf(x); }, {-12, -8, -12},
                                        {12, 40, 12});
    const palp::kernels::VolumeView view(grid);
    CouplingParams p = sceneParams(CouplingMode::AVC, RaySource::VolumeFirstHit);
    Coupling c(&view, nullptr, p);
    ASSERT_TRUE(c.sourceAvailable());
    const Vec proxy(0.13e-3, 0, 0.21e-3);
    // Pressing along the normal, and tilted by 0.2 rad (L = depth / cos 0.2).
    for (double tilt : {0.0, 0.2}) {
        const Vec probe = proxy + 3e-3 * Vec(std::sin(tilt), std::cos(tilt), 0);
        const double L = depth / std::cos(tilt);
        CouplingOutput hit, acc;
        p.source = RaySource::VolumeFirstHit;
        c.setParams(p);
        c.compute(proxy, probe, kZero, kZero, kT1, kT2, hit);
        EXPECT_NEAR(hit.rayLength, L, 0.05 * kVoxel) << tilt;
        EXPECT_DOUBLE_EQ(hit.stiffness, expectedStiffness(p, hit.rayLength));
        // A step sigma of 1e9 / m stops 1 nm past the threshold crossing: the same L.
        p.source = RaySource::VolumeAccumulate;
        c.setParams(p);
        c.compute(proxy, probe, kZero, kZero, kT1, kT2, acc);
        EXPECT_NEAR(acc.rayLength, hit.rayLength, 0.02 * kVoxel) << tilt;
        EXPECT_NEAR(acc.stiffness, hit.stiffness, 0.02 * kVoxel / L * hit.stiffness);
    }
}

// ---------------------------------------------------------------------------------------------
// 3. AVCEC derivatives against analytic gradients

// Tilted plane at distance L0 along the unit normal n from the proxy (n points from the proxy
// to the plane). A ray along unit u hits at L(u) = L0 / (u . n), i.e. L(theta) = L0 / cos(theta -
// theta0) in any plane of directions, so with L_ref / L inside [1, m_max]
// k(u) = k_s L_ref (u . n) / L0 and the angular derivative towards e is dk/dtheta = k_s L_ref
// (e . n) / L0. Surface derivative (fixed u, proxy moved by s t): L = (L0 - s t.n) / (u.n), so
// dk/ds = k_s L_ref (u . n) (t . n) / L0^2.
//
// Sobel truncation: on the spherical stencil k is exactly linear in the unnormalised stencil
// direction's components divided by its norm, so the Sobel sum gives dk/dtheta times
// (sin delta + tan delta / sqrt(1 + 2 tan^2 delta)) / (2 delta) = 1 - 5 delta^2 / 12 + O(delta^4)
// (rows j = 0 contribute sin delta, diagonal rows tan delta / sqrt(1 + 2 tan^2 delta)). The
// tolerance is therefore 0.5 delta^2 of the gradient's size, plus 1e-4 of it for float rays.
// On the surface stencil k ~ 1 / (L0 - s t.n): central differences and the [1 2 1] smoothing
// give a relative error below 2 (h / L0)^2 (3rd derivatives of 1 / (a - x) are 6 / (a - x)^4).
TEST(Coupling, AvcecAngularAndSurfaceDerivativesMatchTiltedPlane) {
    const Vec n = Vec(0.3, 1.0, -0.2).normalized();
    const double L0 = 8e-3;
    MeshScene ms(planeMesh(-n, L0 * n, 0.1));
    CouplingParams p = sceneParams(CouplingMode::AVCEC, RaySource::Mesh);
    const double C = p.baseStiffness * p.referenceLength / L0;  // k along n
    const Vec proxy = kZero;
    Vec a, b;
    palp::kernels::orthonormalBasis(n, a, b);
    int checked = 0;
    for (double delta : {0.1, 0.05, 0.025}) {
        p.bundle.sobelAngle = delta;
        Coupling c(nullptr, &ms.scene, p);
        for (const auto& tilt : std::vector<std::array<double, 2>>{
                 {0, 0}, {0.3, 0}, {0, -0.25}, {0.2, 0.2}, {-0.35, 0.1}}) {
            const Vec u = (n + std::tan(tilt[0]) * a + std::tan(tilt[1]) * b).normalized();
            const double D = 3e-3;
            CouplingOutput out;
            c.compute(proxy, proxy + D * u, kZero, kZero, kT1, kT2, out);
            ASSERT_EQ(out.rays, 17);
            const auto& B = c.bundle();
            EXPECT_NEAR(out.rayLength, L0 / u.dot(n), 1e-6);
            EXPECT_NEAR(out.stiffness, C * u.dot(n), 1e-5 * C);
            // Spherical (probe) derivative.
            const double g1 = C * B.e1.dot(n), g2 = C * B.e2.dot(n);
            const double gNorm = std::hypot(g1, g2);
            const double tolSphere = (0.5 * delta * delta + 1e-4) * C;
            EXPECT_NEAR(out.sphere.g1, g1, tolSphere) << delta;
            EXPECT_NEAR(out.sphere.g2, g2, tolSphere) << delta;
            const double factor =
                (std::sin(delta) +
                 std::tan(delta) / std::sqrt(1 + 2 * std::pow(std::tan(delta), 2))) /
                (2 * delta);
            EXPECT_NEAR(out.sphere.g1, factor * g1, 1e-4 * C);  // the truncation is exactly that
            const Vec eForce = -0.5 * D * (out.sphere.g1 * B.e1 + out.sphere.g2 * B.e2);
            EXPECT_NEAR((out.energyForce - eForce).norm(), 0, 1e-12);
            if (tilt[0] != 0 || tilt[1] != 0) {
                EXPECT_GT(gNorm, 0.1 * C);  // a real gradient was checked
                // The energy force turns the probe towards lower k: away from the normal.
                EXPECT_LT(out.energyForce.dot(n - u.dot(n) * u), 0);
            }
            EXPECT_NEAR(out.energyForce.dot(u), 0, 1e-12);
            // Surface (proxy) derivative.
            const double h = p.bundle.surfaceOffset;
            const double s1 = C * u.dot(n) * kT1.dot(n) / L0, s2 = C * u.dot(n) * kT2.dot(n) / L0;
            const double tolSurface = 2 * (h / L0) * (h / L0) * std::hypot(s1, s2) + 1e-4 * C / L0;
            EXPECT_NEAR(out.surface.g1, s1, tolSurface);
            EXPECT_NEAR(out.surface.g2, s2, tolSurface);
            const Vec pForce = -0.5 * D * D * (s1 * kT1 + s2 * kT2);
            EXPECT_NEAR((out.proxyForce - pForce).norm(), 0,
                        0.5 * D * D * std::sqrt(2.0) * tolSurface);
            EXPECT_NEAR((out.force - (-out.stiffness * D * u + out.energyForce)).norm(), 0, 1e-12);
            ++checked;
        }
    }
    EXPECT_EQ(checked, 15);
}

TEST(Coupling, AvcecAtAPlateEdgePushesAwayFromTheHardSide) {
    // Plate y = 10 mm covering x <= 0 (the hard side is -x); proxy 0.2 mm beside its edge.
    const double depth = 10e-3, s = 0.05;
    MeshScene ms(
        quadMesh(Vec(-s, depth, -s), Vec(0, depth, -s), Vec(0, depth, s), Vec(-s, depth, s)));
    CouplingParams p = sceneParams(CouplingMode::AVCEC, RaySource::Mesh);
    p.bundle.sobelAngle = 0.05;
    p.bundle.surfaceOffset = 0.5e-3;
    Coupling c(nullptr, &ms.scene, p);
    const Vec proxy(0.2e-3, 0, 0);
    const double D = 3e-3;
    CouplingOutput out;
    c.compute(proxy, proxy + Vec(0, D, 0), kZero, kZero, kT1, kT2, out);
    const auto& B = c.bundle();
    ASSERT_NEAR(std::abs(B.e1.x()), 1, 1e-12);  // for d = +y the stencil axes are +-x and +-z
    // Centre misses (x = 0.2 mm): k_s. Surface column i = -1 (x = -0.3 mm) hits at 10 mm.
    const double kSoft = p.baseStiffness, kHard = expectedStiffness(p, depth);
    EXPECT_DOUBLE_EQ(out.stiffness, kSoft);
    const double gs1 = -(kHard - kSoft) * 4 / (8 * p.bundle.surfaceOffset);
    EXPECT_NEAR(out.surface.g1, gs1, 1e-5 * std::abs(gs1));
    EXPECT_NEAR(out.surface.g2, 0, 1e-9);
    // F_py = -1/2 D^2 gs1 t1 points along +x: away from the plate.
    EXPECT_NEAR(out.proxyForce.x(), -0.5 * D * D * gs1, 1e-5 * std::abs(0.5 * D * D * gs1));
    EXPECT_GT(out.proxyForce.x(), 0.1);
    EXPECT_NEAR(out.proxyForce.y(), 0, 1e-12);
    EXPECT_NEAR(out.proxyForce.z(), 0, 1e-12);
    // Spherical stencil: rays tilted by delta towards -x reach y = 10 mm at x = 0.2 - 10 tan delta
    // = -0.3 mm (on the plate), at L = 10 mm * |(tan delta, 1, tan(j delta))|; towards +x they
    // miss.
    const double t = std::tan(p.bundle.sobelAngle);
    const double kEdge = expectedStiffness(p, depth * std::sqrt(1 + t * t));
    const double kDiag = expectedStiffness(p, depth * std::sqrt(1 + 2 * t * t));
    const double g1x = -(2 * (kDiag - kSoft) + 2 * (kEdge - kSoft)) / (8 * p.bundle.sobelAngle);
    EXPECT_NEAR(out.sphere.g1 * B.e1.x(), g1x, 1e-4 * std::abs(g1x));
    EXPECT_NEAR(out.energyForce.x(), -0.5 * D * g1x, 1e-4 * std::abs(0.5 * D * g1x));
    EXPECT_GT(out.energyForce.x(), 0);  // also away from the hard side
    EXPECT_NEAR(out.energyForce.y(), 0, 1e-12);
    EXPECT_NEAR(out.energyForce.z(), 0, 1e-9);
    // Mirrored: proxy on the plate side (x = -0.2 mm) is pushed back the same way (+x): the
    // stiffer surface lies at -x, so lower energy is towards the edge.
    c.compute(Vec(-0.2e-3, 0, 0), Vec(-0.2e-3, D, 0), kZero, kZero, kT1, kT2, out);
    EXPECT_NEAR(out.stiffness, kHard, 1e-6 * kHard);
    EXPECT_GT(out.proxyForce.x(), 0.1);
    // Far from the edge the surface is flat: no proxy force.
    c.compute(Vec(-5e-3, 0, 0), Vec(-5e-3, D, 0), kZero, kZero, kT1, kT2, out);
    EXPECT_NEAR(out.proxyForce.norm(), 0, 1e-9);
}

// ---------------------------------------------------------------------------------------------
// 4. Closed-loop work on the AVC phantom

struct Loop {
    Vec centre, a, b;  // circle centre + r (cos phi a + sin phi b), a, b orthonormal
    double radius;
};

/// Work sum F_pb . dx around @p loop (midpoint rule, @p steps steps) with the proxy held still.
double loopWork(Coupling& c, const Vec& proxy, const Loop& loop, int steps) {
    auto at = [&](double phi) {
        return loop.centre + loop.radius * (std::cos(phi) * loop.a + std::sin(phi) * loop.b);
    };
    CouplingOutput out;
    double w = 0;
    const double dphi = 2 * std::numbers::pi / steps;
    for (int s = 0; s < steps; ++s) {
        c.compute(proxy, at((s + 0.5) * dphi), kZero, kZero, kT1, kT2, out);
        w += out.force.dot(at((s + 1) * dphi) - at(s * dphi));
    }
    return w;
}

/// The AVC phantom (0.5 mm voxels) and the coupling settings of the energy tests.
struct AvcPhantom {
    palp::volume::Volume volume;
    std::unique_ptr<palp::kernels::VolumeView> view;
    CouplingParams params;
    AvcPhantom() {
        palp::volume::PhantomSpec spec;
        spec.params.scene = palp::volume::PhantomScene::Avc;
        spec.voxelSize = 0.5e-3;
        volume = palp::volume::makePhantomVolume(spec);
        view = std::make_unique<palp::kernels::VolumeView>(volume.grid);
        params = sceneParams(CouplingMode::AVC, RaySource::VolumeFirstHit);
        params.firstHit.threshold = 500;  // between soft tissue (40 HU) and rigid (1000 HU)
    }
    /// Sum over @p loops of |closed-loop work| for one mode, Sobel angle and ring.
    double work(const Vec& proxy, const std::vector<Loop>& loops, int steps, CouplingMode mode,
                double delta, int ring, std::vector<double>* each = nullptr) const {
        CouplingParams q = params;
        q.mode = mode;
        q.bundle.sobelAngle = delta;
        q.bundle.ringCount = ring;
        Coupling c(view.get(), nullptr, q);
        double sum = 0;
        for (const Loop& loop : loops) {
            const double w = loopWork(c, proxy, loop, steps);
            if (each) each->push_back(w);
            sum += std::abs(w);
        }
        return sum;
    }
};

const AvcPhantom& avcPhantom() {
    static const AvcPhantom phantom;
    return phantom;
}

/// Circles of 2-3 mm radius, centred 4-5 mm below @p proxy, in vertical and tilted planes.
std::vector<Loop> loopsBelow(const Vec& proxy, double xShift) {
    const Vec x = Vec::UnitX(), y = Vec::UnitY();
    const Vec xz = Vec(1, 0, 1).normalized(), yz = Vec(0, 0.6, 0.8);
    return {
        {proxy + Vec(xShift, 4e-3, 0), x, y, 2e-3},
        {proxy + Vec(-1e-3, 5e-3, 0.5e-3), x, y, 3e-3},
        {proxy + Vec(0.5e-3, 4e-3, 0), xz, y, 2.5e-3},
        {proxy + Vec(xShift, 5e-3, 1e-3), x, yz, 3e-3},
    };
}

// A hit field changes the outputs only by float rounding (its march takes the same samples at
// positions within 1e-3 voxel), and one built for another threshold is ignored after
// setParams() changes the threshold (what a Session does after palp_session_set_params).
TEST(Coupling, HitFieldAgreesToRoundingAndIsIgnoredForAnotherThreshold) {
    const AvcPhantom& ph = avcPhantom();
    const palp::kernels::HitField field(*ph.view, ph.params.firstHit.threshold);
    CouplingParams with = ph.params;
    with.mode = CouplingMode::AVCEC;
    with.firstHit.field = &field;
    CouplingParams without = with;
    without.firstHit.field = nullptr;
    Coupling a(ph.view.get(), nullptr, with), b(ph.view.get(), nullptr, without);
    int hits = 0;
    for (float threshold : {500.0f, 200.0f}) {
        with.firstHit.threshold = without.firstHit.threshold = threshold;
        a.setParams(with);
        b.setParams(without);
        for (int i = 0; i < 50; ++i) {
            const Vec proxy(-6e-3 + 0.25e-3 * i, 0.2e-3 * (i % 7), 1e-3);
            const Vec probe = proxy + 3e-3 * Vec(0.3 * std::sin(0.4 * i), 1, 0.2).normalized();
            CouplingOutput oa, ob;
            a.compute(proxy, probe, kZero, kZero, kT1, kT2, oa);
            b.compute(proxy, probe, kZero, kZero, kT1, kT2, ob);
            if (threshold == ph.params.firstHit.threshold) {
                ASSERT_NEAR(oa.rayLength, ob.rayLength, 1e-3 * kVoxel) << i;
                ASSERT_NEAR(oa.stiffness, ob.stiffness, 1e-3 * ob.stiffness) << i;
                ASSERT_LE((oa.force - ob.force).norm(), 1e-3 * ob.force.norm() + 1e-9) << i;
            } else {  // the field does not match: ignored, bit-equal
                ASSERT_EQ(oa.rayLength, ob.rayLength) << threshold << " " << i;
                ASSERT_EQ(oa.stiffness, ob.stiffness);
                ASSERT_EQ(oa.force, ob.force);
            }
            hits += std::isfinite(oa.rayLength) ? 1 : 0;
        }
    }
    EXPECT_GT(hits, 20);
}

// The headline test. The proxy rests on the surface straight above the plate's +x edge: probe
// directions tilted towards -x hit the plate (L ~ 10 mm, k ~ 900 N/m), directions towards +x
// find nothing within L_max = 40 mm (k = 300 N/m). Plain AVC then does net work around loops
// that cross that edge in direction space; AVCEC's F_pb is the gradient of 1/2 k D^2 and does
// almost none.
//
// No ring here: the ring low-passes k, but the spherical stencil differentiates the raw per-ray
// k, so with a ring F_pb is not the gradient of 1/2 k D^2 and more work remains (printed).
//
// k jumps by 600 N/m across the edge, so -k D d is discontinuous along the loop and the
// midpoint rule makes an error of about Delta k D (dD per step) at each crossing whatever delta
// is (measured with 2000/4000/8000/16000 steps at delta 0.025: 2.6e-4, 1.2e-4, 7.9e-5, 6.1e-5 J).
// With 4000 steps that floor is reached near delta = 0.05, so here the test asserts the 5 %
// goal and the decrease from 0.1 to 0.05; the clean delta^2 convergence is asserted on smooth k
// in the next test.
TEST(Coupling, AvcecClosedLoopWorkVanishesAtThePlateEdge) {
    namespace pg = palp::volume::phantom_geometry;
    const AvcPhantom& ph = avcPhantom();
    const Vec proxy(pg::kAvcPlateHalfWidth, 0, 0);
    const std::vector<Loop> loops = loopsBelow(proxy, 0);
    const int steps = 4000;
    std::vector<double> avc, avcec;
    const double wAvc = ph.work(proxy, loops, steps, CouplingMode::AVC, 0.05, 0, &avc);
    const double w100 = ph.work(proxy, loops, steps, CouplingMode::AVCEC, 0.1, 0);
    const double w050 = ph.work(proxy, loops, steps, CouplingMode::AVCEC, 0.05, 0, &avcec);
    const double w025 = ph.work(proxy, loops, steps, CouplingMode::AVCEC, 0.025, 0);
    const double wRing = ph.work(proxy, loops, steps, CouplingMode::AVCEC, 0.05, 8);
    for (std::size_t i = 0; i < loops.size(); ++i)
        std::printf("edge loop %zu: W_AVC = %.4e J, W_AVCEC(delta 0.05) = %.4e J\n", i, avc[i],
                    avcec[i]);
    std::printf(
        "edge, sum |W|: AVC %.4e J; AVCEC delta 0.1: %.4e J (%.2f %%), 0.05: %.4e J "
        "(%.2f %%), 0.025: %.4e J (%.2f %%); AVCEC 0.05 with an 8-ray ring (alpha 0.1): "
        "%.4e J (%.2f %%)\n",
        wAvc, w100, 100 * w100 / wAvc, w050, 100 * w050 / wAvc, w025, 100 * w025 / wAvc, wRing,
        100 * wRing / wAvc);
    EXPECT_GT(wAvc, 1e-6);
    for (double w : avc) EXPECT_GT(std::abs(w), 1e-3);  // every loop crosses the edge
    EXPECT_LE(w100, 0.05 * wAvc);
    EXPECT_LE(w050, 0.05 * wAvc);
    EXPECT_LE(w025, 0.05 * wAvc);
    EXPECT_LT(w050, w100);
}

// Same loops with the proxy above the plate, 15 mm inside its edges: every ray of the bundle
// hits the plate, so k = k_s L_ref cos(theta) / 10 mm is smooth in the direction and still
// anisotropic. The residual work then comes from the Sobel truncation alone and falls as
// delta^2 (a factor 4 per halving; asserted: at least 2).
TEST(Coupling, AvcecClosedLoopWorkFallsWithTheSobelAngle) {
    const AvcPhantom& ph = avcPhantom();
    const Vec proxy(15e-3, 0, 15e-3);
    const std::vector<Loop> loops = loopsBelow(proxy, 1e-3);
    const int steps = 2000;
    const double wAvc = ph.work(proxy, loops, steps, CouplingMode::AVC, 0.05, 0);
    std::array<double, 3> w{};
    const std::array<double, 3> deltas{0.1, 0.05, 0.025};
    for (std::size_t i = 0; i < 3; ++i)
        w[i] = ph.work(proxy, loops, steps, CouplingMode::AVCEC, deltas[i], 0);
    std::printf(
        "plate interior, sum |W|: AVC %.4e J; AVCEC delta 0.1: %.4e J, 0.05: %.4e J, "
        "0.025: %.4e J\n",
        wAvc, w[0], w[1], w[2]);
    EXPECT_GT(wAvc, 1e-4);
    EXPECT_LE(w[0], 0.05 * wAvc);
    EXPECT_LT(w[1], 0.5 * w[0]);
    EXPECT_LT(w[2], 0.5 * w[1]);
}

// ---------------------------------------------------------------------------------------------
// 5. Allocation-free ticks

TEST(Coupling, ComputeAllocatesNothingInAnyModeAndSource) {
    const double depth = 8e-3;
    MeshScene ms(planeMesh(-Vec::UnitY(), Vec(0, depth, 0), 0.1));
    const palp::test::Plane plane{-Vec::UnitY(), -depth};
    auto grid = palp::test::shapeVolume([&](const Vec& x) { return plane.sdf(x); }, {-12, -8, -12},
                                        {12, 30, 12});
    const palp::kernels::VolumeView view(grid);
    for (CouplingMode mode : {CouplingMode::VC, CouplingMode::AVC, CouplingMode::AVCEC})
        for (RaySource source :
             {RaySource::Mesh, RaySource::VolumeFirstHit, RaySource::VolumeAccumulate})
            for (double tilt : {kNoRayTiltLimit, 0.05}) {  // AVCEC's tilt limit off and on
                CouplingParams p = sceneParams(mode, source);
                p.bundle.ringCount = 4;
                p.maxRayTilt = tilt;
                Coupling c(&view, &ms.scene, p);
                CouplingOutput out;
                double sum = 0;
                const std::uint64_t before = palp::test::allocationCount();
                for (int i = 0; i < 1000; ++i) {
                    const double phi = 0.01 * i;
                    const Vec probe(1e-3 * std::cos(phi), 3e-3, 1e-3 * std::sin(phi));
                    c.compute(kZero, probe, kZero, kZero, kT1, kT2, out);
                    sum += out.force.norm();
                }
                EXPECT_EQ(palp::test::allocationCount() - before, 0u)
                    << static_cast<int>(mode) << " " << static_cast<int>(source) << " " << tilt;
                EXPECT_GT(sum, 0);
                if (mode != CouplingMode::VC) {
                    EXPECT_GT(out.stiffness, p.baseStiffness);  // the plane was seen
                }
            }
}

// ---------------------------------------------------------------------------------------------
// 6. Validation and fall-back

void expectFieldError(const CouplingParams& p, const std::string& field) {
    try {
        validateCouplingParams(p);
        ADD_FAILURE() << "no error for " << field;
    } catch (const palp::ValueError& e) {
        EXPECT_NE(std::string(e.what()).find(field), std::string::npos)
            << "'" << e.what() << "' does not name " << field;
    }
}

TEST(Coupling, ValidationNamesTheField) {
    const CouplingParams good = sceneParams(CouplingMode::AVCEC, RaySource::Mesh);
    EXPECT_NO_THROW(validateCouplingParams(good));
    EXPECT_NO_THROW(validateCouplingParams(CouplingParams{}));
    const double nan = std::numeric_limits<double>::quiet_NaN();
    auto bad = [&](const std::string& field, const std::function<void(CouplingParams&)>& edit) {
        CouplingParams p = good;
        edit(p);
        expectFieldError(p, field);
    };
    bad("baseStiffness", [](CouplingParams& p) { p.baseStiffness = 0; });
    bad("baseStiffness", [&](CouplingParams& p) { p.baseStiffness = nan; });
    bad("referenceLength", [](CouplingParams& p) { p.referenceLength = -1e-3; });
    bad("maxMultiplier", [](CouplingParams& p) { p.maxMultiplier = 0.5; });
    bad("maxStiffness", [](CouplingParams& p) { p.maxStiffness = 100; });
    bad("maxStiffness",
        [](CouplingParams& p) { p.maxStiffness = std::numeric_limits<double>::infinity(); });
    bad("damping", [](CouplingParams& p) { p.damping = -0.1; });
    bad("minDistance", [](CouplingParams& p) { p.minDistance = 0; });
    bad("hardMask", [](CouplingParams& p) { p.hardMask = 0; });
    bad("mode", [](CouplingParams& p) { p.mode = static_cast<CouplingMode>(7); });
    bad("source", [](CouplingParams& p) { p.source = static_cast<RaySource>(-1); });
    bad("length", [](CouplingParams& p) { p.bundle.length = 0; });
    bad("sobelAngle", [](CouplingParams& p) { p.bundle.sobelAngle = 2; });
    bad("ringCount", [](CouplingParams& p) { p.bundle.ringCount = 100; });
    bad("step", [](CouplingParams& p) { p.firstHit.step = 0; });
    bad("tauStop", [](CouplingParams& p) { p.accumulate.tauStop = 0; });
    // The constructor validates too.
    CouplingParams p = good;
    p.damping = -1;
    EXPECT_THROW(Coupling(nullptr, nullptr, p), palp::ValueError);
}

TEST(Coupling, SourceWithoutDataThrowsAtSetUpAndFallsBackToVcAtRunTime) {
    // Set-up: an AVC coupling on a source without its data is an error.
    CouplingParams p = sceneParams(CouplingMode::AVC, RaySource::Mesh);
    EXPECT_THROW(Coupling(nullptr, nullptr, p), palp::ValueError);
    palp::kernels::EmbreeScene empty;
    EXPECT_THROW(Coupling(nullptr, &empty, p), palp::ValueError);
    p.source = RaySource::VolumeFirstHit;
    EXPECT_THROW(Coupling(nullptr, nullptr, p), palp::ValueError);

    // Run time: switching to the Mesh source on a coupling that has only a volume gives VC.
    const palp::test::Plane plane{-Vec::UnitY(), -8e-3};
    auto grid = palp::test::shapeVolume([&](const Vec& x) { return plane.sdf(x); }, {-8, -8, -8},
                                        {8, 30, 8});
    const palp::kernels::VolumeView view(grid);
    p = sceneParams(CouplingMode::AVCEC, RaySource::VolumeFirstHit);
    Coupling c(&view, nullptr, p);
    EXPECT_TRUE(c.sourceAvailable());
    const Vec probe(0, 2e-3, 0);
    CouplingOutput out;
    c.compute(kZero, probe, kZero, kZero, kT1, kT2, out);
    EXPECT_GT(out.stiffness, 2 * p.baseStiffness);  // the plane at 8 mm: k = 1125 N/m
    p.source = RaySource::Mesh;
    c.setParams(p);
    EXPECT_FALSE(c.sourceAvailable());
    c.compute(kZero, probe, kZero, kZero, kT1, kT2, out);
    EXPECT_EQ(out.rays, 0);
    EXPECT_DOUBLE_EQ(out.stiffness, p.baseStiffness);
    EXPECT_NEAR((out.force + p.baseStiffness * probe).norm(), 0, 1e-15);
    EXPECT_EQ(out.proxyForce, kZero);
    // And back.
    p.source = RaySource::VolumeAccumulate;
    c.setParams(p);
    EXPECT_TRUE(c.sourceAvailable());
    c.compute(kZero, probe, kZero, kZero, kT1, kT2, out);
    EXPECT_EQ(out.rays, 17);
}

}  // namespace
