// A deformable body from a scan (deformable_setup.h).

#include "palp/haptics/deformable_setup.h"

namespace palp::haptics {

int autoRegionsLod(const fem::HexMesh& mesh) noexcept {
    const auto cells = mesh.cellCounts();
    return cells[0] % 2 == 0 && cells[1] % 2 == 0 && cells[2] % 2 == 0 ? 2 : 1;
}

fem::BoxFace faceOpposite(const Eigen::Vector3d& press) noexcept {
    int axis = 0;
    press.cwiseAbs().maxCoeff(&axis);
    return static_cast<fem::BoxFace>(2 * axis + (press[axis] > 0 ? 1 : 0));
}

std::shared_ptr<DeformableModel> makeDeformableModel(const volume::Volume& volume,
                                                     const DeformableSetup& setup) {
    const bool autoLod = setup.options.solverKind == DeformableSolver::asyncRegions &&
                         setup.options.regions.lod == 0;
    DeformableOptions options = setup.options;
    if (autoLod) options.regions.lod = 1;  // the lattice decides (below)
    auto model = DeformableModel::fromVolume(volume, setup.voxelize, setup.material,
                                             setup.supportFace, options);
    if (autoLod) {
        const int lod = autoRegionsLod(model->model().mesh());
        if (lod != 1) {
            options.regions.lod = lod;
            model = std::make_shared<DeformableModel>(model->model(), model->fixedNodes(), options);
        }
    }
    return model;
}

}  // namespace palp::haptics
