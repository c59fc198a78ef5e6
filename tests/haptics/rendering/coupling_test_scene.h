#pragma once
// The coupling tests' scene parameters and plate scene (test_coupling.cpp,
// test_coupling_tilt.cpp). Frame: the palpated surface at y = 0, depth along +y.
#include "palp/haptics/rendering/coupling.h"
#include "palp/kernels/embree_scene.h"
#include "palp/kernels/triangle_mesh.h"
#include "ray_test_shapes.h"

namespace palp::test {

/// The proxy's tangent frame (t1 = x, t2 = z: the inward normal -(t1 x t2) is +y) and origin.
inline const Eigen::Vector3d kT1 = Eigen::Vector3d::UnitX();
inline const Eigen::Vector3d kT2 = Eigen::Vector3d::UnitZ();
inline const Eigen::Vector3d kZero = Eigen::Vector3d::Zero();

/// Parameters for a scene whose hard structures lie within 40 mm: L_ref = 30 mm, so that depths
/// of 4 to 30 mm give distinct stiffnesses (300 N/m at the surface, up to 2400 N/m). The
/// thesis's AVCEC, rays from the proxy along d (the analytic checks of test_coupling.cpp assume
/// it); test_coupling_tilt.cpp sets the tilt limit itself.
inline haptics::CouplingParams sceneParams(haptics::CouplingMode mode, haptics::RaySource source) {
    haptics::CouplingParams p;
    p.mode = mode;
    p.source = source;
    p.bundle.length = 40e-3;
    p.bundle.ringCount = 0;
    p.referenceLength = 30e-3;
    p.baseStiffness = 300;
    p.maxMultiplier = 8;
    p.maxStiffness = 2400;
    p.hardMask = kernels::kMaskPlate;
    p.firstHit.threshold = kIso;
    p.accumulate.sigma = kernels::TransferFunction::step(kIso, 1e9f);
    p.accumulate.tauStop = 1;
    p.maxRayTilt = haptics::kNoRayTiltLimit;
    return p;
}

/// One committed scene holding @p mesh as a plate.
struct MeshScene {
    kernels::EmbreeScene scene;
    explicit MeshScene(const kernels::TriangleMesh& mesh) {
        scene.addRigidMesh(mesh, kernels::kMaskPlate);
        scene.commit();
    }
};

}  // namespace palp::test
