#pragma once
/// @file
/// How a deformable body is made from a scan: the voxelisation, the material, the supports and
/// the solver in one struct, and the one function that builds the model from them. `palp
/// palpate --deformable` and the C API (palp_scene_make_deformable) both build their tissue
/// here, so a body made through either is the same body.

#include <Eigen/Core>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "palp/fem/hex_mesh.h"
#include "palp/fem/material.h"
#include "palp/fem/voxelize.h"
#include "palp/haptics/tissue/deformable.h"
#include "palp/haptics/tissue/material_table.h"
#include "palp/kernels/embree_scene.h"
#include "palp/volume/volume.h"

namespace palp::haptics {

/// The skin a contact will slide over: a rectangle across the press (centre, unit axes u and
/// v, full extents, metres) seen along @p press (into the body). On a patient's curved skin the
/// regions' default slide zone (the lattice face of the regions centre, a phantom's flat skin)
/// is empty; this patch gives the regions the nodes the contact will reach
/// (fem::AsyncRegionsOptions::slideNodes), so that every move of the contact over it is laid
/// out from the whole body's factor instead of a factorisation of its own (seconds).
struct SlidePatch {
    Eigen::Vector3d centre{Eigen::Vector3d::Zero()};
    Eigen::Vector3d u{Eigen::Vector3d::UnitX()}, v{Eigen::Vector3d::UnitZ()};
    Eigen::Vector3d press{Eigen::Vector3d::UnitY()};
    double extentU = 0, extentV = 0;
};

/// The skin of @p model under @p patch: its free surface nodes (loadNodes()) whose rest
/// positions lie in the rectangle and within 1.5 element edges (along the press) of the
/// frontmost such node of their element-sized column, i.e. the skin the press meets first and
/// not a surface behind it (the far side of a head, a cavity's wall). Sorted.
/// @throw palp::ValueError for a non-finite patch, axes that are not unit and orthogonal to
/// each other and to the press, or extents not positive.
std::vector<int> skinNodesUnder(const DeformableModel& model, const SlidePatch& patch);

/// @p model's boundary surface at rest as a committed scene (kMaskSurface, robust): the surface
/// its proxy meets before anything moves, on which a path is laid (the skin's patch and heights).
/// @throw palp::Error from Embree.
std::unique_ptr<kernels::EmbreeScene> restSurfaceScene(const DeformableModel& model);

/// Everything that makes a deformable body from a scan (defaults: `palp palpate
/// --deformable`'s: 5 mm cells, tissue above -200, bone above 500 fixed, tissue enclosed by
/// bone dropped, 5 kPa, nu 0.45, alpha 60 1/s, a 3 mm filter, the whole-mesh explicit solver at
/// 1 kHz).
struct DeformableSetup {
    /// Element size, the tissue and bone thresholds (a cell above boneThreshold is bone: its
    /// nodes are fixed; +infinity: no bone), optionally a per-cell modulus, and insideBone:
    /// fem::InsideBone::drop here, so a head CT gives the scalp and face on the skull, not the
    /// brain inside it (the phantoms have no tissue enclosed by bone and are unchanged).
    fem::VoxelizeOptions voxelize = [] {
        fem::VoxelizeOptions v;
        v.boneThreshold = 500;
        v.insideBone = fem::InsideBone::drop;
        return v;
    }();
    /// The tissue (uniform unless voxelize.youngsFromValue or materialTable is set). With
    /// material.law fem::MaterialLaw::neoHookean the whole-mesh explicit solver runs TLED, the
    /// regions TLED in their primary with a linear far field.
    fem::ElasticMaterial material = [] {
        fem::ElasticMaterial m;
        m.dampingAlpha = 60;
        return m;
    }();
    /// The nodes on this face of the tissue's lattice are fixed (a support); none: only bone
    /// (and then the scan must have some).
    std::optional<fem::BoxFace> supportFace;
    /// Filter, solver kind, regions. regions.lod 0 asks for autoRegionsLod(); the servo period
    /// goes in tickSeconds and regions.tickSeconds (setPeriod()). The regions as `palp palpate`
    /// and the C API run them: 60 seeds, the secondary at 100 Hz, the lod from the lattice (the
    /// regions' own 30 seeds at 50 Hz and lod 1 left the contact's neighbourhood in the
    /// secondary: on the bone phantom's circle, live, 9-41 ticks a 10 s window at the 3.3 N
    /// clamp where `palp palpate` had none).
    DeformableOptions options = [] {
        DeformableOptions o;
        o.regions.primaryNodes = 60;
        o.regions.secondaryRate = 100;
        o.regions.lod = 0;
        return o;
    }();
    /// true: options.solverKind is chosen by chooseSolver() (`palp palpate --fem-solver auto`,
    /// the default there): the whole mesh where it makes the tick, the regions otherwise.
    bool autoSolver = false;
    /// Materials from the scan (material_table.h): when set, makeDeformableModel() applies it
    /// over voxelize.youngsFromValue and material's Poisson ratio, density and nominal modulus
    /// (applyMaterialTable(), after the thresholds above).
    std::shared_ptr<const MaterialTable> materialTable;
    /// With the regions: the skin the contact will slide over (skinNodesUnder() becomes
    /// options.regions.slideNodes, before the lod is chosen). Unset: the regions' default.
    std::optional<SlidePatch> slidePatch;

    /// Sets the period the sessions will step the body with, s (tickSeconds and, for the
    /// regions, regions.tickSeconds).
    void setPeriod(double seconds) noexcept {
        options.tickSeconds = seconds;
        options.regions.tickSeconds = seconds;
    }
};

/// The regions' secondary level of detail `lod = 0` stands for: 2 where it divides every cell
/// count of @p mesh (a coarser secondary keeps the zone a contact slides over without a
/// factorisation small on phantom-sized bodies), 1 otherwise.
int autoRegionsLod(const fem::HexMesh& mesh) noexcept;
/// The regions' lod for @p model (built with any lod): autoRegionsLod() of its lattice, raised
/// from 2 to 4 (where 4 divides every cell count) when the zone a contact slides over without a
/// factorisation (fem::AsyncRegions::slideZoneDofs, around regionsCentreNode()) is over
/// regions.slideZoneMaxDofs at lod 2 and within it at 4. The bone phantom at 2.5 mm cells
/// (40 x 20 x 40, 60 seeds): 5,292 dofs at lod 2, 1,089 at lod 4; at 5 mm: lod 2 (1,452).
/// @throw palp::ValueError as fem::AsyncRegions::slideZoneDofs.
int autoRegionsLod(const DeformableModel& model);

/// What chooseSolver() chose and why.
struct SolverChoice {
    DeformableSolver solver = DeformableSolver::wholeMeshExplicit;
    /// Element updates one whole-mesh tick takes: elements x explicit substeps per tick.
    double elementSubsteps = 0;
    /// The most chooseSolver() gives the whole mesh (kWholeMeshElementSubsteps).
    double budget = 0;
    std::string reason;  ///< one line, e.g. "whole mesh: 4,000 elements x 2 substeps = 8,000 ..."
};

/// Element updates (elements x substeps) a whole-mesh explicit tick may take and still leave
/// the servo its rays and proxy within 1 ms: 8,000 (~0.75 ms at ~94 ns an element-substep on
/// a 2-core AVX-512 VM, and at ~90 ns on a 2-core AVX2 one since the element kernel got its
/// AVX2 shape; the head CT at 5 mm, 14,339 elements x 2 substeps, took 2.7 ms a tick).
inline constexpr double kWholeMeshElementSubsteps = 8000;

/// The whole-mesh explicit solver when elements x substeps per tick (at its safety factor and
/// tickSeconds) is within kWholeMeshElementSubsteps, else the asynchronous regions, for either
/// law (a neo-Hookean body: TLED on the whole mesh, or in the regions' primary with a linear
/// far field; the reason says which).
SolverChoice chooseSolver(const fem::FemModel& model, const DeformableOptions& options);

/// The face opposite the one a press along @p press (any non-zero vector; its largest
/// component's axis) goes into: the support of a body pressed from the other side.
fem::BoxFace faceOpposite(const Eigen::Vector3d& press) noexcept;

/// Builds the body of @p setup from @p volume (DeformableModel::fromVolume), with the solver
/// chosen by chooseSolver() when setup.autoSolver (reported in @p choice when given) and
/// regions.lod 0 resolved by autoRegionsLod().
/// @throw palp::ValueError naming the field (voxelisation, material, options, a body too stiff
/// for its period, no fixed node, a scan
/// value no row of the material table covers); palp::Error from the material table.
std::shared_ptr<DeformableModel> makeDeformableModel(const volume::Volume& volume,
                                                     const DeformableSetup& setup,
                                                     SolverChoice* choice = nullptr);

}  // namespace palp::haptics
