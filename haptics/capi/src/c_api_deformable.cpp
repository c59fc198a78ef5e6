// The C API's deformable scenes (see c_api_internal.h): the options struct and its defaults,
// the scene, its surface topology and the deformed surface a viewer reads from a session.

#include <array>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <limits>
#include <memory>
#include <string>

#include "c_api_internal.h"
#include "palp/base/bounds.h"
#include "palp/base/validate.h"
#include "palp/haptics/scene.h"
#include "palp/haptics/tissue/deformable_setup.h"
#include "palp/haptics/tissue/error_control.h"

namespace ph = palp::haptics;

namespace palp::capi {
namespace {

/// Every plain number of palp_deformable_options with its bounds (palp/base/bounds.h), checked
/// in this order; the others (thresholds with a "none", enums, counts) after them.
struct DeformableField {
    double palp_deformable_options::*field;
    const char* name;
    const Bounds* bounds;
};

constexpr Bounds kContactDampingRatio{0, 10, ""};
constexpr std::array kDeformableFields = {
    DeformableField{&palp_deformable_options::element_size, "element_size", &bounds::kSpacing},
    DeformableField{&palp_deformable_options::tissue_threshold, "tissue_threshold",
                    &bounds::kVolumeValue},
    DeformableField{&palp_deformable_options::youngs_modulus, "youngs_modulus",
                    &bounds::kYoungsModulus},
    DeformableField{&palp_deformable_options::poisson_ratio, "poisson_ratio",
                    &bounds::kPoissonRatio},
    DeformableField{&palp_deformable_options::density, "density", &bounds::kDensity},
    DeformableField{&palp_deformable_options::damping_alpha, "damping_alpha",
                    &bounds::kMassDamping},
    DeformableField{&palp_deformable_options::damping_beta, "damping_beta",
                    &bounds::kStiffnessDamping},
    DeformableField{&palp_deformable_options::filter_width, "filter_width", &bounds::kSpan},
    DeformableField{&palp_deformable_options::contact_damping_ratio, "contact_damping_ratio",
                    &kContactDampingRatio},
    DeformableField{&palp_deformable_options::period, "period", &bounds::kPeriod},
    DeformableField{&palp_deformable_options::secondary_rate, "secondary_rate",
                    &bounds::kSolverRate}};

constexpr int kMaxPrimaryNodes = 100000;

std::string field(const char* name) { return std::string("palp_deformable_options.") + name; }

/// C -> C++, checking every field. @throw palp::ValueError naming the C field.
ph::DeformableSetup toSetup(const palp_deformable_options& c) {
    for (const DeformableField& f : kDeformableFields) {
        requireWithin(field(f.name), c.*f.field, *f.bounds);
    }
    const bool noBone =
        std::isnan(c.bone_threshold) || c.bone_threshold == std::numeric_limits<double>::infinity();
    if (!noBone) {
        requireWithin(field("bone_threshold") + " (NAN or INFINITY: no bone)", c.bone_threshold,
                      bounds::kVolumeValue);
    }
    const int face = rawEnum(c.support_face);
    if (face < PALP_FACE_NONE || face > PALP_FACE_Z_MAX) {
        throwExpected(field("support_face"), "PALP_FACE_NONE .. PALP_FACE_Z_MAX (0..6)",
                      std::to_string(face));
    }
    const int inside = rawEnum(c.inside_bone);
    if (inside != PALP_INSIDE_BONE_KEEP && inside != PALP_INSIDE_BONE_DROP) {
        throwExpected(field("inside_bone"), "PALP_INSIDE_BONE_KEEP or PALP_INSIDE_BONE_DROP (0, 1)",
                      std::to_string(inside));
    }
    const int solver = rawEnum(c.solver);
    if (solver != PALP_FEM_WHOLE_MESH && solver != PALP_FEM_REGIONS && solver != PALP_FEM_AUTO) {
        throwExpected(field("solver"),
                      "PALP_FEM_WHOLE_MESH, PALP_FEM_REGIONS or PALP_FEM_AUTO (0..2)",
                      std::to_string(solver));
    }
    const int law = rawEnum(c.material_law);
    if (law != PALP_MATERIAL_LINEAR && law != PALP_MATERIAL_NEO_HOOKEAN) {
        throwExpected(field("material_law"),
                      "PALP_MATERIAL_LINEAR or PALP_MATERIAL_NEO_HOOKEAN (0, 1)",
                      std::to_string(law));
    }
    if (c.primary_nodes < 1 || c.primary_nodes > kMaxPrimaryNodes) {
        throwExpected(field("primary_nodes"), "1.." + std::to_string(kMaxPrimaryNodes),
                      std::to_string(c.primary_nodes));
    }
    if (c.lod != 0 && c.lod != 1 && c.lod != 2 && c.lod != 4) {
        throwExpected(field("lod"), "0 (automatic), 1, 2 or 4", std::to_string(c.lod));
    }
    const bool noCentre = std::isnan(c.regions_centre[0]) && std::isnan(c.regions_centre[1]) &&
                          std::isnan(c.regions_centre[2]);
    if (!noCentre) {
        for (int i = 0; i < 3; ++i) {
            requireWithin(field("regions_centre[") + std::to_string(i) + "] (all NAN: none)",
                          c.regions_centre[i], bounds::kPosition);
        }
    }

    ph::DeformableSetup s;
    s.voxelize.elementSize = c.element_size;
    s.voxelize.tissueThreshold = c.tissue_threshold;
    s.voxelize.boneThreshold = noBone ? std::numeric_limits<double>::infinity() : c.bone_threshold;
    s.voxelize.insideBone =
        inside == PALP_INSIDE_BONE_DROP ? fem::InsideBone::drop : fem::InsideBone::keep;
    s.material.youngsModulus = c.youngs_modulus;
    s.material.poissonRatio = c.poisson_ratio;
    s.material.density = c.density;
    s.material.dampingAlpha = c.damping_alpha;
    s.material.dampingBeta = c.damping_beta;
    s.material.law =
        law == PALP_MATERIAL_NEO_HOOKEAN ? fem::MaterialLaw::neoHookean : fem::MaterialLaw::linear;
    if (c.material_table) {
        try {
            s.materialTable = ph::MaterialTable::named(c.material_table);
        } catch (const palp::Error& e) {
            throw palp::ValueError(field("material_table") + ": " + e.what());
        }
    }
    if (face != PALP_FACE_NONE) s.supportFace = static_cast<fem::BoxFace>(face - 1);
    s.options.filterWidth = c.filter_width;
    s.options.contactDampingRatio = c.contact_damping_ratio;
    s.setPeriod(c.period);
    s.options.solverKind = solver == PALP_FEM_REGIONS ? ph::DeformableSolver::asyncRegions
                                                      : ph::DeformableSolver::wholeMeshExplicit;
    s.autoSolver = solver == PALP_FEM_AUTO;
    s.options.regions.primaryNodes = c.primary_nodes;
    s.options.regions.secondaryRate = c.secondary_rate;
    s.options.regions.lod = c.lod;
    s.options.regions.threaded = c.threaded != 0;
    if (!noCentre) s.options.regionsCentre = vec(c.regions_centre);
    return s;
}

/// What makeDeformableModel() reported of @p model's solver, as C.
palp_solver_choice toC(const ph::SolverChoice& choice, bool chosen,
                       const ph::DeformableModel& model) noexcept {
    palp_solver_choice c{};
    const bool regions = model.options().solverKind == ph::DeformableSolver::asyncRegions;
    c.solver = regions ? PALP_FEM_REGIONS : PALP_FEM_WHOLE_MESH;
    c.chosen = chosen ? 1 : 0;
    c.element_substeps = chosen ? choice.elementSubsteps : 0;
    c.budget = chosen ? choice.budget : 0;
    c.lod = regions ? model.options().regions.lod : 0;
    std::snprintf(c.reason, sizeof c.reason, "%s", choice.reason.c_str());
    return c;
}

/// The scene's deformable model; PALP_ERROR_STATE (and nullptr) on a rigid scene.
const ph::DeformableModel* modelOf(const palp_scene* scene, const char* function) {
    const ph::DeformableModel* m = scene->scene->deformable().get();
    if (!m) {
        fail(PALP_ERROR_STATE,
             (std::string(function) + ": expected a deformable scene (palp_scene_make_deformable), "
                                      "found a rigid one")
                 .c_str());
    }
    return m;
}

}  // namespace

double deformablePeriod(const palp_scene& scene) noexcept {
    const auto& m = scene.scene->deformable();
    if (!m) return 0;
    return m->options().solverKind == ph::DeformableSolver::asyncRegions
               ? m->options().regions.tickSeconds
               : m->options().tickSeconds;
}

}  // namespace palp::capi

using namespace palp::capi;

extern "C" {

void palp_deformable_options_default(palp_deformable_options* options) {
    if (!options) return;
    const ph::DeformableSetup d;
    palp_deformable_options& c = *options;
    std::memset(&c, 0, sizeof c);
    c.element_size = d.voxelize.elementSize;
    c.tissue_threshold = d.voxelize.tissueThreshold;
    c.bone_threshold = d.voxelize.boneThreshold;
    c.support_face = PALP_FACE_Y_MAX;
    c.youngs_modulus = d.material.youngsModulus;
    c.poisson_ratio = d.material.poissonRatio;
    c.density = d.material.density;
    c.damping_alpha = d.material.dampingAlpha;
    c.damping_beta = d.material.dampingBeta;
    c.filter_width = d.options.filterWidth;
    c.contact_damping_ratio = d.options.contactDampingRatio;
    c.period = d.options.tickSeconds;
    c.solver = PALP_FEM_AUTO;  // palp palpate's and Python's: the regions on a patient's CT
    c.primary_nodes = d.options.regions.primaryNodes;  // palp palpate's (DeformableSetup)
    c.secondary_rate = d.options.regions.secondaryRate;
    c.lod = d.options.regions.lod;
    c.threaded = d.options.regions.threaded ? 1 : 0;
    for (double& x : c.regions_centre) x = std::numeric_limits<double>::quiet_NaN();
    c.inside_bone = d.voxelize.insideBone == palp::fem::InsideBone::drop ? PALP_INSIDE_BONE_DROP
                                                                         : PALP_INSIDE_BONE_KEEP;
    c.material_law = PALP_MATERIAL_LINEAR;
    c.material_table = nullptr;
}

palp_status palp_scene_make_deformable(const palp_volume* volume, double hard_iso,
                                       const palp_deformable_options* options, palp_scene** out) {
    if (!volume) return nullArgument("palp_scene_make_deformable", "volume");
    if (!options) return nullArgument("palp_scene_make_deformable", "options");
    if (!out) return nullArgument("palp_scene_make_deformable", "out");
    return guarded([&] {
        if (!std::isnan(hard_iso)) {  // NAN: no hard meshes
            palp::requireWithin("palp_scene_make_deformable: hard_iso (NAN: none)", hard_iso,
                                palp::bounds::kVolumeValue);
        }
        const ph::DeformableSetup setup = toSetup(*options);
        ph::SceneOptions so;
        so.surfaceIso = std::numeric_limits<double>::quiet_NaN();  // the body's surface
        so.hardIso = hard_iso;
        std::shared_ptr<ph::Scene> scene = ph::Scene::fromVolume(volume->volume, so);
        ph::SolverChoice choice;
        std::shared_ptr<ph::DeformableModel> model;
        try {
            model = ph::makeDeformableModel(volume->volume, setup, &choice);
        } catch (const palp::ValueError& e) {
            // The library names its own fields; say which call and struct made the body.
            throw palp::ValueError(std::string("palp_scene_make_deformable: ") + e.what() +
                                   " (from palp_deformable_options)");
        }
        auto handle = std::make_unique<palp_scene>();
        handle->solver = toC(choice, setup.autoSolver, *model);
        scene->setDeformable(std::move(model));
        handle->scene = std::move(scene);
        *out = handle.release();
        return PALP_OK;
    });
}

int palp_scene_is_deformable(const palp_scene* scene) {
    return scene && scene->scene->deformable() ? 1 : 0;
}

palp_status palp_scene_solver(const palp_scene* scene, palp_solver_choice* out) {
    if (!scene) return nullArgument("palp_scene_solver", "scene");
    if (!out) return nullArgument("palp_scene_solver", "out");
    if (!modelOf(scene, "palp_scene_solver")) return PALP_ERROR_STATE;
    *out = scene->solver;
    return PALP_OK;
}

palp_status palp_scene_error_estimate(const palp_scene* scene, double strain, double frequency,
                                      palp_error_estimate* out) {
    if (!scene) return nullArgument("palp_scene_error_estimate", "scene");
    if (!out) return nullArgument("palp_scene_error_estimate", "out");
    const ph::DeformableModel* m = modelOf(scene, "palp_scene_error_estimate");
    if (!m) return PALP_ERROR_STATE;
    return guarded([&] {
        const std::pair<const char*, double> inputs[] = {{"strain", strain},
                                                         {"frequency", frequency}};
        for (const auto& [name, v] : inputs) {
            if (!std::isnan(v) && !(std::isfinite(v) && v >= 0))
                palp::throwExpected(std::string("palp_scene_error_estimate: ") + name,
                                    "a finite value >= 0 or NAN", std::to_string(v));
        }
        const ph::ErrorEstimate e = ph::estimateBodyError(*m, strain, frequency);
        out->percent = e.percent;
        out->in_range = e.inRange() ? 1 : 0;
        return PALP_OK;
    });
}

palp_status palp_scene_surface_size(const palp_scene* scene, size_t* vertex_count,
                                    size_t* triangle_count) {
    if (!scene) return nullArgument("palp_scene_surface_size", "scene");
    const ph::DeformableModel* m = modelOf(scene, "palp_scene_surface_size");
    if (!m) return PALP_ERROR_STATE;
    if (vertex_count) *vertex_count = m->surface().vertices.size();
    if (triangle_count) *triangle_count = m->surface().triangles.size();
    return PALP_OK;
}

palp_status palp_scene_surface_topology(const palp_scene* scene, uint32_t* triangles,
                                        size_t triangle_capacity, float* rest_vertices,
                                        size_t vertex_capacity) {
    if (!scene) return nullArgument("palp_scene_surface_topology", "scene");
    const ph::DeformableModel* m = modelOf(scene, "palp_scene_surface_topology");
    if (!m) return PALP_ERROR_STATE;
    const palp::fem::SurfaceMesh& s = m->surface();
    return guarded([&] {
        if (triangles && triangle_capacity < s.triangles.size()) {
            palp::throwExpected(
                "palp_scene_surface_topology: triangle_capacity",
                "at least the surface's " + std::to_string(s.triangles.size()) + " triangles",
                std::to_string(triangle_capacity));
        }
        if (rest_vertices && vertex_capacity < s.vertices.size()) {
            palp::throwExpected(
                "palp_scene_surface_topology: vertex_capacity",
                "at least the surface's " + std::to_string(s.vertices.size()) + " vertices",
                std::to_string(vertex_capacity));
        }
        if (triangles) {
            for (std::size_t t = 0; t < s.triangles.size(); ++t) {
                for (std::size_t k = 0; k < 3; ++k) triangles[3 * t + k] = s.triangles[t][k];
            }
        }
        if (rest_vertices) {
            for (std::size_t v = 0; v < s.vertices.size(); ++v) {
                for (Eigen::Index k = 0; k < 3; ++k)
                    rest_vertices[3 * v + static_cast<std::size_t>(k)] = s.vertices[v][k];
            }
        }
        return PALP_OK;
    });
}

palp_status palp_session_latest_surface(palp_session* session, float* vertices,
                                        size_t vertex_capacity, uint64_t* tick) {
    if (!session) return nullArgument("palp_session_latest_surface", "session");
    if (!vertices) return nullArgument("palp_session_latest_surface", "vertices");
    const ph::SurfaceFrame* f = session->session->latestSurface();
    if (!f) {
        return fail(PALP_ERROR_STATE,
                    "palp_session_latest_surface: expected a session on a deformable scene, "
                    "found one on a rigid scene");
    }
    const std::size_t n = f->positions.size();
    if (vertex_capacity < n / 3) {
        return guarded([&]() -> palp_status {
            palp::throwExpected("palp_session_latest_surface: vertex_capacity",
                                "at least the surface's " + std::to_string(n / 3) + " vertices",
                                std::to_string(vertex_capacity));
        });
    }
    std::memcpy(vertices, f->positions.data(), n * sizeof(float));
    if (tick) *tick = f->tick;
    return PALP_OK;
}

}  // extern "C"
