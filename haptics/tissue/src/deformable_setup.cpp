// A deformable body from a scan (deformable_setup.h).

#include "palp/haptics/tissue/deformable_setup.h"

#include <cstdio>

#include "palp/fem/async_regions.h"
#include "palp/fem/explicit_solver.h"

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

SolverChoice chooseSolver(const fem::FemModel& model, const DeformableOptions& options) {
    SolverChoice c;
    c.budget = kWholeMeshElementSubsteps;
    const double substeps =
        fem::explicitSubstepsPerTick(model, options.solver.safetyFactor, options.tickSeconds);
    const double elements = model.mesh().elementCount();
    c.elementSubsteps = elements * substeps;
    c.solver = c.elementSubsteps <= c.budget ? DeformableSolver::wholeMeshExplicit
                                             : DeformableSolver::asyncRegions;
    char line[256];
    std::snprintf(line, sizeof line, "%s: %.0f elements x %.0f substeps a tick = %.0f, %s %.0f",
                  c.solver == DeformableSolver::wholeMeshExplicit ? "whole mesh" : "regions",
                  elements, substeps, c.elementSubsteps,
                  c.solver == DeformableSolver::wholeMeshExplicit ? "within" : "over", c.budget);
    c.reason = line;
    return c;
}

std::shared_ptr<DeformableModel> makeDeformableModel(const volume::Volume& volume,
                                                     const DeformableSetup& setup,
                                                     SolverChoice* choice) {
    DeformableOptions options = setup.options;
    if (setup.autoSolver) options.solverKind = DeformableSolver::wholeMeshExplicit;
    const bool autoLod = setup.options.regions.lod == 0;
    if (autoLod) options.regions.lod = 1;  // the lattice decides (below)
    auto model = DeformableModel::fromVolume(volume, setup.voxelize, setup.material,
                                             setup.supportFace, options);
    if (setup.autoSolver) {
        const SolverChoice c = chooseSolver(model->model(), options);
        if (choice) *choice = c;
        if (c.solver == DeformableSolver::asyncRegions) {
            options.solverKind = DeformableSolver::asyncRegions;
            model = model->withOptions(options);
        }
    } else if (choice) {
        choice->solver = options.solverKind;
        choice->reason = options.solverKind == DeformableSolver::asyncRegions ? "regions: asked"
                                                                              : "whole mesh: asked";
    }
    if (options.solverKind == DeformableSolver::asyncRegions && autoLod) {
        const int lod = autoRegionsLod(*model);
        if (lod != 1) {
            options.regions.lod = lod;
            model = model->withOptions(options);
        }
    }
    return model;
}

}  // namespace palp::haptics
