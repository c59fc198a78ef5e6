// A deformable body from a scan (deformable_setup.h).

#include "palp/haptics/tissue/deformable_setup.h"

#include "palp/fem/async_regions.h"

namespace palp::haptics {

int autoRegionsLod(const fem::HexMesh& mesh) noexcept {
    const auto cells = mesh.cellCounts();
    return cells[0] % 2 == 0 && cells[1] % 2 == 0 && cells[2] % 2 == 0 ? 2 : 1;
}

int autoRegionsLod(const DeformableModel& model) {
    const fem::HexMesh& mesh = model.model().mesh();
    const int lod = autoRegionsLod(mesh);
    if (lod != 2 || model.options().solverKind != DeformableSolver::asyncRegions) return lod;
    // The zone a contact slides over without a factorisation grows with the pressed face's
    // coarse node count: on a fine lattice (the bone phantom at 2.5 mm: 5,292 dofs at lod 2)
    // it is over the cap, every move of the contact is factorised (seconds) and a sliding
    // contact leaves the primary. A coarser secondary keeps the zone small.
    fem::AsyncRegionsOptions o = model.options().regions;
    o.drive = fem::ContactDrive::force;
    o.threaded = false;
    o.watchNodes.clear();
    const std::vector<int> centre{model.regionsCentreNode()};
    for (const int candidate : {2, 4}) {
        const auto cells = mesh.cellCounts();
        if (cells[0] % candidate != 0 || cells[1] % candidate != 0 || cells[2] % candidate != 0)
            break;
        o.lod = candidate;
        if (fem::AsyncRegions::slideZoneDofs(model.model(), model.constraints(), centre, o) <=
            o.slideZoneMaxDofs)
            return candidate;
    }
    return lod;
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
        const int lod = autoRegionsLod(*model);
        if (lod != 1) {
            options.regions.lod = lod;
            model = std::make_shared<DeformableModel>(model->model(), model->fixedNodes(), options);
        }
    }
    return model;
}

}  // namespace palp::haptics
