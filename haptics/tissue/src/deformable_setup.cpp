// A deformable body from a scan (deformable_setup.h).

#include "palp/haptics/tissue/deformable_setup.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>
#include <string>

#include "palp/base/error.h"
#include "palp/base/validate.h"
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
    const bool within = c.elementSubsteps <= c.budget;
    char line[256];
    c.solver = within ? DeformableSolver::wholeMeshExplicit : DeformableSolver::asyncRegions;
    // A neo-Hookean body runs TLED on the whole mesh, or in the regions' primary with a linear
    // far field (the same budget decides).
    const bool nh = model.material().law == fem::MaterialLaw::neoHookean;
    std::snprintf(line, sizeof line, "%s: %.0f elements x %.0f substeps a tick = %.0f, %s %.0f%s",
                  within ? "whole mesh" : "regions", elements, substeps, c.elementSubsteps,
                  within ? "within" : "over", c.budget,
                  !nh      ? ""
                  : within ? " (neo-Hookean: TLED)"
                           : " (neo-Hookean: TLED in the primary, linear far field)");
    c.reason = line;
    return c;
}

std::unique_ptr<kernels::EmbreeScene> restSurfaceScene(const DeformableModel& model) {
    const fem::SurfaceMesh& s = model.surface();
    kernels::TriangleMesh mesh;
    mesh.positions.reserve(3 * s.vertices.size());
    for (const Eigen::Vector3f& v : s.vertices)
        mesh.positions.insert(mesh.positions.end(), {v.x(), v.y(), v.z()});
    mesh.indices.reserve(3 * s.triangles.size());
    for (const auto& t : s.triangles) mesh.indices.insert(mesh.indices.end(), t.begin(), t.end());
    auto scene = std::make_unique<kernels::EmbreeScene>(/*robust=*/true);
    scene->addRigidMesh(mesh, kernels::kMaskSurface);
    scene->commit();
    return scene;
}

std::vector<int> skinNodesUnder(const DeformableModel& model, const SlidePatch& patch) {
    const auto unit = [](const Eigen::Vector3d& a) { return std::abs(a.norm() - 1.0) <= 1e-6; };
    if (!patch.centre.allFinite() || !patch.u.allFinite() || !patch.v.allFinite() ||
        !patch.press.allFinite() || !unit(patch.u) || !unit(patch.v) || !unit(patch.press) ||
        std::abs(patch.u.dot(patch.v)) > 1e-6 || std::abs(patch.u.dot(patch.press)) > 1e-6 ||
        std::abs(patch.v.dot(patch.press)) > 1e-6)
        throw ValueError(
            "deformable slidePatch: expected finite unit axes u, v and press, orthogonal to each "
            "other, found u (" +
            std::to_string(patch.u.x()) + ", " + std::to_string(patch.u.y()) + ", " +
            std::to_string(patch.u.z()) + "), v (" + std::to_string(patch.v.x()) + ", " +
            std::to_string(patch.v.y()) + ", " + std::to_string(patch.v.z()) + "), press (" +
            std::to_string(patch.press.x()) + ", " + std::to_string(patch.press.y()) + ", " +
            std::to_string(patch.press.z()) + ")");
    if (!(patch.extentU > 0 && patch.extentV > 0 && std::isfinite(patch.extentU) &&
          std::isfinite(patch.extentV)))
        throw ValueError("deformable slidePatch: expected positive finite extents, found " +
                         std::to_string(patch.extentU) + " x " + std::to_string(patch.extentV) +
                         " m");
    const fem::HexMesh& mesh = model.model().mesh();
    const double edge = mesh.edge();
    const int nu = std::max(1, static_cast<int>(std::ceil(patch.extentU / edge)));
    const int nv = std::max(1, static_cast<int>(std::ceil(patch.extentV / edge)));
    // Per element-sized column of the rectangle: the frontmost candidate's depth along the press.
    std::vector<double> front(static_cast<std::size_t>(nu) * static_cast<std::size_t>(nv),
                              std::numeric_limits<double>::infinity());
    struct Candidate {
        int node;
        std::size_t column;
        double depth;
    };
    std::vector<Candidate> inside;
    for (const int n : model.loadNodes()) {
        const Eigen::Vector3d r = mesh.nodePosition(n) - patch.centre;
        const double a = r.dot(patch.u) + 0.5 * patch.extentU;
        const double b = r.dot(patch.v) + 0.5 * patch.extentV;
        if (!(a >= 0 && a <= patch.extentU && b >= 0 && b <= patch.extentV)) continue;
        const int i = std::min(nu - 1, static_cast<int>(a / edge));
        const int j = std::min(nv - 1, static_cast<int>(b / edge));
        const std::size_t column = static_cast<std::size_t>(i) * static_cast<std::size_t>(nv) +
                                   static_cast<std::size_t>(j);
        const double depth = r.dot(patch.press);
        front[column] = std::min(front[column], depth);
        inside.push_back({n, column, depth});
    }
    std::vector<int> out;
    for (const Candidate& c : inside)
        if (c.depth <= front[c.column] + 1.5 * edge) out.push_back(c.node);
    std::sort(out.begin(), out.end());
    return out;
}

std::shared_ptr<DeformableModel> makeDeformableModel(const volume::Volume& volume,
                                                     const DeformableSetup& setup,
                                                     SolverChoice* choice) {
    DeformableOptions options = setup.options;
    if (setup.autoSolver) options.solverKind = DeformableSolver::wholeMeshExplicit;
    const bool autoLod = setup.options.regions.lod == 0;
    if (autoLod) options.regions.lod = 1;  // the lattice decides (below)
    fem::VoxelizeOptions voxelize = setup.voxelize;
    fem::ElasticMaterial material = setup.material;
    if (setup.materialTable) applyMaterialTable(setup.materialTable, voxelize, material);
    auto model =
        DeformableModel::fromVolume(volume, voxelize, material, setup.supportFace, options);
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
    if (options.solverKind == DeformableSolver::asyncRegions && setup.slidePatch) {
        options.regions.slideNodes = skinNodesUnder(*model, *setup.slidePatch);
        model = model->withOptions(options);
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
