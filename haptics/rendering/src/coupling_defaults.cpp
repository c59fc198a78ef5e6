#include "palp/haptics/rendering/coupling_defaults.h"

namespace palp::haptics {

namespace {

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
            break;
        case volume::PhantomScene::Bone:
            p.mode = CouplingMode::AVCEC;
            break;
        case volume::PhantomScene::Stiffness:
            p.mode = CouplingMode::AVC;
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
