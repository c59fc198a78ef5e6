// AVCEC's ray tilt limit (CouplingParams::maxRayTilt, docs/algorithms.md section 3, "The rays'
// tilt"): where the rays leave and along what, against a flat and a tilted plate; the force on
// the probe and on the proxy against the numerical gradient of the potential E = 1/2 k D^2 they
// come from; AVC and the limit turned off keep the thesis's rays from the proxy along d.
//
// Frame: the contact plane y = 0 with tangents t1 = x, t2 = z, so the inward normal
// -(t1 x t2) is +y (depth), as in test_coupling.cpp.

#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <exception>
#include <string>
#include <vector>

#include "coupling_test_scene.h"
#include "mesh_test_shapes.h"
#include "palp/haptics/rendering/coupling.h"

namespace {

using namespace palp::haptics;
using palp::test::kT1;
using palp::test::kT2;
using palp::test::kZero;
using palp::test::MeshScene;
using palp::test::planeMesh;
using palp::test::sceneParams;
using Vec = Eigen::Vector3d;

CouplingParams meshParams(CouplingMode mode, double maxRayTilt) {
    CouplingParams p = sceneParams(mode, RaySource::Mesh);
    p.maxRayTilt = maxRayTilt;
    return p;
}

/// The probe D from the proxy (at the origin), tilted @p theta from +y towards azimuth @p phi.
Vec probeAt(double D, double theta, double phi) {
    return D *
           Vec(std::sin(theta) * std::cos(phi), std::cos(theta), std::sin(theta) * std::sin(phi));
}

Vec centreOrigin(const palp::kernels::RayBundle& b) { return Vec(b.ox[0], b.oy[0], b.oz[0]); }
Vec centreAxis(const palp::kernels::RayBundle& b) { return Vec(b.dx[0], b.dy[0], b.dz[0]); }

// A plate L0 below the contact plane. The centre ray leaves from the contact plane, along the
// axis tilted theta_c tanh(theta / theta_c) in d's azimuth, through the probe, and is
// L0 / cos(that tilt) long; so a probe dragged 69 degrees off the normal still looks 5.7 degrees
// off it, under itself. With the limit off (pi/2) and in AVC the ray is the thesis's, from the
// proxy along d.
TEST(CouplingTilt, RaysLeaveAboveTheProbeTiltedAtMostThetaC) {
    const double L0 = 8e-3, D = 2e-3, thetaC = 0.1;
    MeshScene plate(planeMesh(-Vec::UnitY(), Vec(0, L0, 0), 0.1));
    Coupling limited(nullptr, &plate.scene, meshParams(CouplingMode::AVCEC, thetaC));
    Coupling thesis(nullptr, &plate.scene, meshParams(CouplingMode::AVCEC, kNoRayTiltLimit));
    Coupling avc(nullptr, &plate.scene, meshParams(CouplingMode::AVC, thetaC));
    for (double theta : {0.0, 0.05, 0.3, 0.7, 1.2}) {
        for (double phi : {0.0, 2.0}) {
            const Vec probe = probeAt(D, theta, phi);
            const Vec d = probe / D;
            CouplingOutput out;
            limited.compute(kZero, probe, kZero, kZero, kT1, kT2, out);
            const double tilt = thetaC * std::tanh(theta / thetaC);
            const Vec axis = centreAxis(limited.bundle());
            const Vec origin = centreOrigin(limited.bundle());
            EXPECT_NEAR(std::acos(std::clamp(axis.y(), -1.0, 1.0)), tilt, 1e-5) << theta;
            EXPECT_NEAR(origin.y(), 0, 1e-7) << theta;  // on the contact plane
            EXPECT_NEAR((probe - origin).cross(axis).norm(), 0, 1e-7)
                << theta;     // through the probe
            if (theta > 0) {  // in d's azimuth
                EXPECT_GT(axis.x() * d.x() + axis.z() * d.z(), 0) << theta;
                EXPECT_NEAR(axis.x() * d.z() - axis.z() * d.x(), 0, 1e-7) << theta;
            }
            EXPECT_NEAR(out.rayLength, L0 / std::cos(tilt), 1e-6) << theta;
            for (Coupling* c : {&thesis, &avc}) {
                CouplingOutput o;
                c->compute(kZero, probe, kZero, kZero, kT1, kT2, o);
                EXPECT_NEAR((centreAxis(c->bundle()) - d).norm(), 0, 1e-6) << theta;
                EXPECT_NEAR(centreOrigin(c->bundle()).norm(), 0, 1e-9) << theta;
                EXPECT_NEAR(o.rayLength, L0 / std::cos(theta), 1e-6 + 1e-5 / std::cos(theta))
                    << theta;
            }
        }
    }
}

// The potential E = 1/2 k D^2 (k of the centre ray, Coupling's own energy) over a tilted plate,
// where k depends smoothly on the rays' origin and axis, differentiated numerically: its
// gradient over the probe is minus the force the coupling renders (spring and spherical term),
// and its tangential gradient over the proxy minus the force the session moves the proxy with
// (-F_pb + F_py), with fine stencils (their truncation is then 1e-4 of the gradient). Without
// the origin's share (the surface stencil's term the limit adds to the probe's force) the
// probe's force misses the gradient by 2-3 % of the force, 10-15 times the tolerance; with the
// azimuthal part 10 % too large it fails as well.
TEST(CouplingTilt, ForcesAreTheGradientsOfThePotential) {
    const Vec n = Vec(0.3, 1.0, -0.2).normalized();
    const double L0 = 8e-3, D = 2.5e-3;
    MeshScene plate(planeMesh(-n, L0 * n, 0.1));
    CouplingParams p = meshParams(CouplingMode::AVCEC, 0.2);
    p.bundle.sobelAngle = 0.01;
    p.bundle.surfaceOffset = 0.05e-3;
    Coupling c(nullptr, &plate.scene, p);
    const auto energy = [&](const Vec& proxy, const Vec& probe) {
        CouplingOutput o;
        c.compute(proxy, probe, kZero, kZero, kT1, kT2, o);
        return o.energy;
    };
    const double eps = 2e-6;
    int checked = 0;
    for (const auto& [theta, phi] : std::vector<std::array<double, 2>>{
             {0.15, 0.0}, {0.4, 1.0}, {0.8, -2.0}, {1.2, 0.5}, {0.6, 3.0}}) {
        const Vec probe = probeAt(D, theta, phi);
        CouplingOutput out;
        c.compute(kZero, probe, kZero, kZero, kT1, kT2, out);
        Vec gradProbe, gradProxy;
        for (int a = 0; a < 3; ++a) {
            const Vec e = eps * Vec::Unit(a);
            gradProbe[a] = (energy(kZero, probe + e) - energy(kZero, probe - e)) / (2 * eps);
            gradProxy[a] = (energy(e, probe) - energy(-e, probe)) / (2 * eps);
        }
        const double scale = out.force.norm();
        EXPECT_NEAR((out.force + gradProbe).norm(), 0, 2e-3 * scale)
            << "theta " << theta << " phi " << phi << ": force " << out.force.transpose()
            << ", -grad E " << -gradProbe.transpose();
        // The energy term is a real part of it (not just the spring along d).
        EXPECT_GT(out.energyForce.norm(), 0.05 * scale) << theta;
        const Vec onProxy = -out.force + out.proxyForce;
        for (const Vec& t : {kT1, kT2})
            EXPECT_NEAR(onProxy.dot(t), -gradProxy.dot(t), 2e-3 * scale)
                << "theta " << theta << " phi " << phi;
        ++checked;
    }
    EXPECT_EQ(checked, 5);
}

TEST(CouplingTilt, ValidationNamesTheField) {
    for (double bad : {0.0, 0.005, 1.6, -0.1, std::nan("")}) {
        CouplingParams p = meshParams(CouplingMode::AVCEC, bad);
        try {
            validateCouplingParams(p);
            ADD_FAILURE() << bad << " accepted";
        } catch (const std::exception& e) {
            EXPECT_NE(std::string(e.what()).find("coupling maxRayTilt"), std::string::npos)
                << e.what();
        }
    }
    CouplingParams ok = meshParams(CouplingMode::AVCEC, kNoRayTiltLimit);
    EXPECT_NO_THROW(validateCouplingParams(ok));
}

}  // namespace
