#ifndef PALP_PALP_DEFORMABLE_H
#define PALP_PALP_DEFORMABLE_H
/**
 * @file
 * palp's C API, deformable scenes: a volume's tissue voxelised into a hexahedral FEM body (its
 * law, its materials from the volume's values, its solver), the choice of solver, the error its
 * regions make, and the surface's topology. palp/palp.h includes this header; include that one
 * (its conventions, handles and statuses hold here).
 */

#include "palp/palp.h"

#ifdef __cplusplus
extern "C" {
#endif

/** A face of the tissue's hexahedral lattice (its world box), whose nodes are fixed. */
typedef enum palp_face {
    PALP_FACE_NONE = 0, /**< no support face: only the bone rule fixes nodes */
    PALP_FACE_X_MIN = 1,
    PALP_FACE_X_MAX = 2,
    PALP_FACE_Y_MIN = 3,
    PALP_FACE_Y_MAX = 4, /**< the phantoms' back (they are pressed along +y) */
    PALP_FACE_Z_MIN = 5,
    PALP_FACE_Z_MAX = 6
} palp_face;

/** The FEM solver a deformable scene's sessions run every tick. */
typedef enum palp_fem_solver {
    PALP_FEM_WHOLE_MESH = 0, /**< explicit, the whole mesh every tick (small bodies) */
    PALP_FEM_REGIONS = 1,    /**< asynchronous regions: an explicit primary region around the
                                  contact every tick, an implicit secondary at secondary_rate */
    PALP_FEM_AUTO = 2        /**< palp chooses once, when the scene is made (`palp palpate
                                  --fem-solver auto`): the whole mesh where elements x explicit
                                  substeps a tick is within its budget (8,000: it then makes the
                                  1 kHz tick), the regions otherwise (a patient's CT); see
                                  palp_scene_solver() for the choice and why */
} palp_fem_solver;

/** The tissue's law (palp_deformable_options.material_law, `palp palpate --material`). */
typedef enum palp_material_law {
    PALP_MATERIAL_LINEAR = 0,     /**< small strain (every solver) */
    PALP_MATERIAL_NEO_HOOKEAN = 1 /**< large strain, the same small-strain E and nu (TLED): on
                                       the whole mesh, or in the regions' primary with a linear
                                       far field */
} palp_material_law;

/** What happens to tissue enclosed by bone (the brain inside a skull). */
typedef enum palp_inside_bone {
    PALP_INSIDE_BONE_KEEP = 0, /**< kept in the body */
    PALP_INSIDE_BONE_DROP = 1  /**< dropped: soft cells with bone on both sides along at least
                                    two lattice axes (unless they face the air outside), and
                                    bone cells touching no kept soft tissue */
} palp_inside_bone;

/** How a deformable body is made from a volume (the tissue of `palp palpate --deformable`).
 *  Always start from palp_deformable_options_default(); every field is checked (all of them,
 *  whatever the solver) and a refusal names it as "palp_deformable_options.<field>". */
typedef struct palp_deformable_options {
    double element_size;     /**< hexahedron edge, m (1e-6..0.1; default 5e-3) */
    double tissue_threshold; /**< a cell is tissue where the volume at its centre is above this
                                  (volume units; default -200 HU) */
    double bone_threshold;   /**< a tissue cell above this is bone: its nodes are fixed (default
                                  500 HU); NAN or INFINITY: no bone rule */
    palp_face support_face;  /**< the nodes of this face are fixed too (default PALP_FACE_Y_MAX;
                                  at least one node must be fixed by the face or the bone) */
    double youngs_modulus;   /**< E, Pa (1..1e12; default 5e3) */
    double poisson_ratio;    /**< nu, in (-1, 0.5) (default 0.45) */
    double density;          /**< kg/m^3 (1..1e5; default 1000) */
    double damping_alpha;    /**< mass-proportional Rayleigh damping, 1/s (0..1e4; default 60) */
    double damping_beta;     /**< stiffness-proportional Rayleigh damping, s (0..1; default 0) */
    double filter_width;     /**< sigma of the Gaussian that spreads the contact over surface
                                  nodes, m (0..10; 0: the nearest node; default 3e-3) */
    double contact_damping_ratio; /**< damping of the contact, ratio of critical (0..10; 1) */
    /** Servo period of the sessions that will use the scene, s (must equal their
     *  palp_session_params.period; default 1e-3). */
    double period;
    /** Default PALP_FEM_AUTO (as `palp palpate` and Python's Scene.make_deformable): the
     *  whole mesh on the phantoms, the regions on a head CT. */
    palp_fem_solver solver;
    /* PALP_FEM_REGIONS (and PALP_FEM_AUTO when it takes the regions) only (checked always): */
    int primary_nodes;        /**< seed nodes of the primary region (1..100000; default 60) */
    double secondary_rate;    /**< secondary solves per second, Hz (1..1000; default 100) */
    int lod;                  /**< secondary level of detail 1, 2 or 4; 0 (default): 2 where it
                                   divides the lattice's cell counts, else 1 */
    int threaded;             /**< non-zero (default): the secondary on its own threads, for
                                   live sessions; 0: synchronous and deterministic (offline) */
    double regions_centre[3]; /**< world point, m: the region starts at the free surface node
                                   nearest it (put it under the path); all NAN (default): the
                                   first free surface node */
    /** Tissue enclosed by bone (only with a bone threshold): default PALP_INSIDE_BONE_DROP,
     *  as `palp palpate --deformable` (a head CT gives the scalp on the skull, not the brain);
     *  PALP_INSIDE_BONE_KEEP keeps it. */
    palp_inside_bone inside_bone;
    palp_material_law material_law; /**< default PALP_MATERIAL_LINEAR */
    /** NULL (default): the uniform youngs_modulus; "ct": palp's CT table; else a CSV table's
     *  path (docs/algorithms.md 5.2): each element's E, and nu and density, from the values. */
    const char* material_table;
} palp_deformable_options;

/** Fills @p options with palp's defaults (those of `palp palpate --deformable`). */
void palp_deformable_options_default(palp_deformable_options* options);

/** A deformable scene from a volume: the tissue between @p options' thresholds voxelised into
 *  a hexahedral FEM body (fixed on the support face and in bone), whose deformed boundary is
 *  the surface the proxy slides on; the volume for the volume ray sources (sampled where the
 *  tissue was at rest); the iso-surface at @p hard_iso as hard meshes for PALP_SOURCE_MESH
 *  (NAN: none). Every session on the scene gets its own body. Takes about as long as
 *  voxelising and, for PALP_FEM_REGIONS, factorising the body (seconds on ~33^3 nodes).
 *  Errors: PALP_ERROR_INVALID_ARGUMENT naming the field (also for a body too stiff for its
 *  period, or one with no fixed node). */
palp_status palp_scene_make_deformable(const palp_volume* volume, double hard_iso,
                                       const palp_deformable_options* options, palp_scene** out);

/** 1 for a deformable scene, 0 otherwise (also for NULL). */
int palp_scene_is_deformable(const palp_scene* scene);

/** The solver a deformable scene's sessions run, and why (palp_scene_solver()). */
typedef struct palp_solver_choice {
    palp_fem_solver solver; /**< PALP_FEM_WHOLE_MESH or PALP_FEM_REGIONS (never AUTO) */
    int chosen;             /**< 1: PALP_FEM_AUTO chose it; 0: the options asked for it */
    /** Element updates one whole-mesh tick would take: elements x explicit substeps a tick
     *  (PALP_FEM_AUTO only; 0 when the solver was asked for). */
    double element_substeps;
    double budget; /**< the most PALP_FEM_AUTO gives the whole mesh (8,000; 0 when asked) */
    int lod;       /**< the regions' secondary level of detail in force (1, 2 or 4; lod 0
                        resolved); 0 for the whole mesh */
    /** One line, e.g. "regions: 14339 elements x 2 substeps a tick = 28678, over 8000" or
     *  "whole mesh: asked" (NUL-terminated; cut to fit). */
    char reason[160];
} palp_solver_choice;

/** What solver @p scene's sessions run and why. PALP_ERROR_STATE on a rigid scene. */
palp_status palp_scene_solver(const palp_scene* scene, palp_solver_choice* out);

/** The contact-force error palp's error table predicts for a deformable scene's regions
 *  (docs/error_analysis.md, "Lookup table and control"). */
typedef struct palp_error_estimate {
    /** Relative error of the contact force, percent: the table's 95th percentile of the error
     *  sweep's peak-force error at the body's material, regions (lod, primary size, secondary
     *  rate) and the input; 0 for a body on the whole mesh. */
    double percent;
    int in_range; /**< 1: every coordinate inside the sweep's ranges; 0: some clamped to them */
} palp_error_estimate;

/** The error predicted for @p scene's regions at an input of @p strain (the contact's
 *  displacement amplitude over the body's thickness along the press) and @p frequency (Hz);
 *  NAN for either: the worst the table holds over it (what `palp palpate --error-budget`
 *  chooses for). PALP_ERROR_STATE on a rigid scene; PALP_ERROR_INVALID_ARGUMENT for an
 *  infinite or negative strain or frequency. */
palp_status palp_scene_error_estimate(const palp_scene* scene, double strain, double frequency,
                                      palp_error_estimate* out);

/** The deformable surface's size: vertices and triangles (either pointer may be NULL). The
 *  topology never changes. PALP_ERROR_STATE on a rigid scene. */
palp_status palp_scene_surface_size(const palp_scene* scene, size_t* vertex_count,
                                    size_t* triangle_count);

/** The deformable surface's topology, for drawing: @p triangles receives triangle_count x 3
 *  vertex indices (counter-clockwise seen from outside) and @p rest_vertices vertex_count x 3
 *  rest positions (world, m); either may be NULL. Each capacity (in triangles, in vertices)
 *  must hold the whole surface (PALP_ERROR_INVALID_ARGUMENT otherwise, nothing written).
 *  PALP_ERROR_STATE on a rigid scene. */
palp_status palp_scene_surface_topology(const palp_scene* scene, uint32_t* triangles,
                                        size_t triangle_capacity, float* rest_vertices,
                                        size_t vertex_capacity);

#ifdef __cplusplus
}
#endif

#endif /* PALP_PALP_DEFORMABLE_H */
