#include "palp/haptics/rendering/coupling_defaults.h"

#include <array>

namespace palp::haptics {

namespace {

/// The stiffness boxes' rendered multiplier over soft (m0) and hard (m1) tissue.
constexpr double kStiffSoftMultiplier = 1.25;
constexpr double kStiffHardMultiplier = 3.25;
constexpr double kStiffTauStop = 3;
/// The AVCEC plates' accumulate stop: half the 2 mm plate's optical depth.
constexpr double kAvcecTauStop = 1;

/// sigma(v) for the stiffness boxes: under the fat layer a column of value v stops an
/// accumulate ray at L = d0 + tau / sigma(v), so sigma(v) = tau / (L_ref / m(v) - d0) makes the
/// rendered k = k_s L_ref / L linear in v (m0 at soft, m1 at hard tissue): the box's stiffness
/// field, not a surface of it. d0 is the fat's thickness plus half a voxel of trilinear blur.
kernels::TransferFunction stiffnessFieldSigma(double referenceLength) {
    const volume::PhantomParams phantom;
    const volume::PhantomMaterials& m = phantom.materials;
    const double d0 = phantom.fatThickness + 0.5e-3;
    constexpr int kRamp = kernels::TransferFunction::kMaxNodes - 1;
    std::array<std::array<float, 2>, kRamp + 1> nodes{};
    // Below soft tissue the ramp falls to 0 halfway to fat, so fat stops nothing.
    nodes[0] = {static_cast<float>(0.5 * (m.fatHu + m.softHu)), 0.0f};
    for (int i = 0; i < kRamp; ++i) {
        const double t = static_cast<double>(i) / (kRamp - 1);
        const double mult =
            kStiffSoftMultiplier + (kStiffHardMultiplier - kStiffSoftMultiplier) * t;
        const double sigma = kStiffTauStop / (referenceLength / mult - d0);
        nodes[static_cast<std::size_t>(i + 1)] = {
            static_cast<float>(m.softHu + (m.hardHu - m.softHu) * t), static_cast<float>(sigma)};
    }
    return kernels::TransferFunction(nodes);
}

CouplingParams commonDefaults() {
    CouplingParams p;
    p.mode = CouplingMode::AVC;
    p.source = RaySource::VolumeFirstHit;
    p.bundle.length = 0.040;
    p.bundle.ringCount = 0;
    p.bundle.sobelAngle = 0.1;
    p.bundle.surfaceOffset = 1e-3;
    p.firstHit.threshold = 500;
    p.firstHit.step = 0.5e-3;
    p.accumulate.sigma = kernels::TransferFunction::step(500.0f, 1000.0f);
    p.accumulate.tauStop = 3;
    p.accumulate.step = 0.5e-3;
    p.baseStiffness = 300;
    p.referenceLength = 0.040;
    p.maxMultiplier = 8;
    p.maxStiffness = 2400;
    return p;
}

}  // namespace

CouplingParams sceneCouplingDefaults(volume::PhantomScene scene) {
    CouplingParams p = commonDefaults();
    switch (scene) {
        case volume::PhantomScene::Avc:
            p.mode = CouplingMode::AVC;
            p.source = RaySource::VolumeAccumulate;
            break;
        case volume::PhantomScene::Avcec:
            p.mode = CouplingMode::AVCEC;
            p.referenceLength = 0.020;
            // The plate is the scene: 2 mm of sigma 1/mm give tau 2, so an accumulate ray with
            // the common tau_stop 3 passed it and felt k_s everywhere (the raster's map showed
            // nothing). 1 stops it 1 mm into the plate, as first-hit stops at its top.
            p.accumulate.tauStop = kAvcecTauStop;
            // The plates' surface stencil: with the rays leaving above the probe
            // (maxRayTilt) the hand feels the surface term at an edge; over 2 mm it maps the
            // plates as the 2 mm map resolves them (shapes, seeds 1, 2: |F| IoU 0.86 -> 0.89
            // from 1 mm, the largest force 3.1 -> 2.0 N; docs/algorithms.md section 3).
            p.bundle.surfaceOffset = 2e-3;
            break;
        case volume::PhantomScene::Bone:
            p.mode = CouplingMode::AVCEC;
            break;
        case volume::PhantomScene::Stiffness:
            p.mode = CouplingMode::AVC;
            p.source = RaySource::VolumeAccumulate;
            p.accumulate.sigma = stiffnessFieldSigma(p.referenceLength);
            p.accumulate.tauStop = kStiffTauStop;
            p.firstHit.threshold = 200;
            break;
        case volume::PhantomScene::Tumour:
            // The inclusion (+200 HU) is what the rays look for, not the soft tissue (+40).
            p.mode = CouplingMode::AVCEC;
            p.firstHit.threshold = 120;
            break;
    }
    return p;
}

CouplingParams scanCouplingDefaults() {
    CouplingParams p = commonDefaults();
    p.firstHit.threshold = 300;
    return p;
}

}  // namespace palp::haptics
