/* Deformable scenes through the C API, compiled as C11: the bone phantom voxelised into FEM
 * tissue (palp_scene_make_deformable), a simulated VC press held on it, the force (out of the
 * tissue, k D in the hold, the tissue pushed by the reaction) and the deformed surface a viewer
 * reads (palp_session_latest_surface: the vertices under the probe moved in by the proxy's
 * depth, the support face not at all); then a short live run whose surface a viewer reads
 * while the servo thread runs. Returns non-zero on the first failure. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "c_check.h"
#include "palp/palp.h"

#define STIFFNESS 300.0 /* N/m: VC */
#define DEPTH 4e-3      /* m: the path's press below the rest surface */

static double norm3(const double v[3]) { return sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]); }

/* The bone phantom as 5 mm FEM tissue on its back face, and the path's centre above it. */
static palp_scene* make_scene(palp_fem_solver solver, double centre[3]) {
    palp_volume* volume = NULL;
    CHECK(palp_volume_make_phantom("bone", 0, NULL, 2e-3, &volume) == PALP_OK);
    if (!volume) return NULL;
    double lo[3], hi[3];
    CHECK(palp_volume_geometry(volume, NULL, lo, hi) == PALP_OK);
    centre[0] = 0.5 * (lo[0] + hi[0]);
    centre[1] = lo[1] - 5e-3; /* 5 mm above the surface (y = 0 faces -y) */
    centre[2] = 0.5 * (lo[2] + hi[2]);
    palp_deformable_options o;
    palp_deformable_options_default(&o);
    o.solver = solver;
    o.threaded = 0; /* deterministic offline steps */
    o.regions_centre[0] = centre[0];
    o.regions_centre[1] = 0;
    o.regions_centre[2] = centre[2];
    palp_scene* scene = NULL;
    CHECK(palp_scene_make_deformable(volume, NAN, &o, &scene) == PALP_OK);
    palp_volume_release(volume); /* the scene keeps what it needs */
    return scene;
}

static void make_session_inputs(const double centre[3], palp_session_params* p,
                                palp_trajectory* t) {
    palp_session_params_default(p);
    p->mode = PALP_MODE_VC;
    p->stiffness = STIFFNESS;
    p->max_stiffness = STIFFNESS;
    CHECK(palp_trajectory_default(PALP_TRAJECTORY_PRESS, t) == PALP_OK);
    memcpy(t->centre, centre, sizeof t->centre);
    t->direction[0] = 0;
    t->direction[1] = 1;
    t->direction[2] = 0;
    t->depth = 5e-3 + DEPTH;
    t->press_seconds = 0.5;
    t->hold_seconds = 1.5;
}

static void test_press_and_surface(void) {
    double centre[3];
    palp_scene* scene = make_scene(PALP_FEM_WHOLE_MESH, centre);
    if (!scene) return;
    CHECK(palp_scene_is_deformable(scene) == 1);
    size_t nv = 0, nt = 0;
    CHECK(palp_scene_surface_size(scene, &nv, &nt) == PALP_OK);
    CHECK(nv > 100 && nt > 100);
    uint32_t* tris = malloc(3 * nt * sizeof *tris);
    float* rest = malloc(3 * nv * sizeof *rest);
    float* now = malloc(3 * nv * sizeof *now);
    if (!tris || !rest || !now) abort();
    CHECK(palp_scene_surface_topology(scene, tris, nt - 1, NULL, 0) == PALP_ERROR_INVALID_ARGUMENT);
    CHECK(strstr(palp_last_error(), "triangle_capacity") != NULL);
    CHECK(palp_scene_surface_topology(scene, tris, nt, rest, nv) == PALP_OK);
    uint32_t maxIndex = 0;
    for (size_t i = 0; i < 3 * nt; ++i) maxIndex = tris[i] > maxIndex ? tris[i] : maxIndex;
    CHECK(maxIndex == nv - 1);       /* every vertex used, none beyond */
    float minY = 1e9f, maxY = -1e9f; /* the pressed face (y = 0 on a phantom), the support */
    for (size_t v = 0; v < nv; ++v) {
        minY = rest[3 * v + 1] < minY ? rest[3 * v + 1] : minY;
        maxY = rest[3 * v + 1] > maxY ? rest[3 * v + 1] : maxY;
    }
    CHECK(fabs(minY) < 5e-3f);
    centre[1] = minY - 5e-3; /* start 5 mm above the tissue */

    palp_session_params params;
    palp_trajectory path;
    make_session_inputs(centre, &params, &path);
    palp_session* session = NULL;
    params.period = 5e-4; /* the scene was made for 1 kHz */
    CHECK(palp_session_create_simulated(scene, &params, &path, &session) ==
          PALP_ERROR_INVALID_ARGUMENT);
    CHECK(strstr(palp_last_error(), "palp_deformable_options.period") != NULL);
    params.period = 1e-3;
    CHECK(palp_session_create_simulated(scene, &params, &path, &session) == PALP_OK);
    if (!session) return;

    /* Before the first tick the viewer sees the rest surface. */
    uint64_t tick = 99;
    CHECK(palp_session_latest_surface(session, now, nv - 1, &tick) == PALP_ERROR_INVALID_ARGUMENT);
    CHECK(palp_session_latest_surface(session, now, nv, &tick) == PALP_OK);
    CHECK(tick == 0 && memcmp(now, rest, 3 * nv * sizeof *now) == 0);

    /* Press 0.5 s, then hold: over the last 0.5 s of the hold the force is the VC spring,
     * k D out of the tissue, steady, and the tissue gets its reaction. */
    palp_snapshot s;
    CHECK(palp_session_step(session, 1500, &s) == PALP_OK);
    double fMin = 1e9, fMax = 0;
    for (int i = 0; i < 500; ++i) {
        CHECK(palp_session_step(session, 1, &s) == PALP_OK);
        const double f = norm3(s.force);
        fMin = f < fMin ? f : fMin;
        fMax = f > fMax ? f : fMax;
    }
    CHECK(s.contact_count > 0 && s.fem_flags == 0 && s.faulted == 0 && s.clamped == 0);
    CHECK(s.force[1] < -0.05); /* out of the tissue (-y), a firm press */
    CHECK(fabs(s.force[0]) < 0.05 * -s.force[1] && fabs(s.force[2]) < 0.05 * -s.force[1]);
    CHECK(fabs(norm3(s.force) - STIFFNESS * s.distance) < 0.05 * norm3(s.force));
    CHECK(fMax - fMin < 0.05 * fMax); /* a steady hold */
    for (int a = 0; a < 3; ++a) CHECK(fabs(s.tissue_force[a] + s.force[a]) < 1e-3);
    CHECK(s.contact_node >= 0);
    /* The proxy went in with the tissue, the probe deeper still. */
    const double proxyDepth = s.proxy[1] - minY;
    CHECK(proxyDepth > 0.5e-3 && s.proxy[1] < s.probe[1]);

    /* The surface: the vertices near the contact moved in by about the proxy's depth, the
     * support face not at all, the most moved one as far as the snapshot says. */
    CHECK(palp_session_latest_surface(session, now, nv, &tick) == PALP_OK);
    CHECK(tick == s.tick);
    double nearDisp = 0, nearDist = 1e9, maxDisp = 0, maxSupport = 0, maxFar = 0;
    for (size_t v = 0; v < nv; ++v) {
        double d[3], lateral = 0, moved = 0;
        for (size_t a = 0; a < 3; ++a) {
            d[a] = (double)now[3 * v + a] - rest[3 * v + a];
            moved += d[a] * d[a];
        }
        moved = sqrt(moved);
        lateral = hypot(rest[3 * v] - s.proxy[0], rest[3 * v + 2] - s.proxy[2]);
        maxDisp = moved > maxDisp ? moved : maxDisp;
        if (rest[3 * v + 1] == maxY) maxSupport = moved > maxSupport ? moved : maxSupport;
        if (rest[3 * v + 1] == minY && lateral < nearDist) {
            nearDist = lateral;
            nearDisp = d[1];
        }
        if (rest[3 * v + 1] == minY && lateral > 20e-3) maxFar = moved > maxFar ? moved : maxFar;
    }
    CHECK(nearDist < 5e-3);
    CHECK(nearDisp > 0.7 * proxyDepth && nearDisp < 1.3 * proxyDepth);
    CHECK(maxSupport == 0.0);
    CHECK(maxFar < 0.25 * nearDisp);
    CHECK(fabs(maxDisp - s.max_displacement) < 1e-6);
    printf(
        "deformable press: F %.3f N (k D %.3f N), ripple %.2f %%, proxy %.2f mm in, vertex "
        "under it %.2f mm, far surface <= %.3f mm, %zu vertices, %zu triangles\n",
        norm3(s.force), STIFFNESS * s.distance, 100 * (fMax - fMin) / fMax, 1e3 * proxyDepth,
        1e3 * nearDisp, 1e3 * maxFar, nv, nt);

    palp_session_release(session);
    palp_scene_release(scene);
    free(tris);
    free(rest);
    free(now);
}

/* Rigid scenes have no surface to read; bad options are refused naming the field. */
static void test_refusals(void) {
    palp_scene* rigid = NULL;
    CHECK(palp_scene_create_empty(&rigid) == PALP_OK);
    CHECK(palp_scene_is_deformable(rigid) == 0);
    size_t nv = 0;
    CHECK(palp_scene_surface_size(rigid, &nv, NULL) == PALP_ERROR_STATE);
    CHECK(strstr(palp_last_error(), "deformable") != NULL);
    palp_session_params params;
    palp_session_params_default(&params);
    params.mode = PALP_MODE_VC;
    palp_trajectory path;
    CHECK(palp_trajectory_default(PALP_TRAJECTORY_PRESS, &path) == PALP_OK);
    palp_session* session = NULL;
    CHECK(palp_session_create_simulated(rigid, &params, &path, &session) == PALP_OK);
    float v[3];
    CHECK(palp_session_latest_surface(session, v, 1, NULL) == PALP_ERROR_STATE);
    palp_session_release(session);
    palp_scene_release(rigid);

    palp_volume* volume = NULL;
    CHECK(palp_volume_make_phantom("bone", 0, NULL, 2e-3, &volume) == PALP_OK);
    palp_deformable_options o;
    palp_deformable_options_default(&o);
    o.youngs_modulus = -5;
    palp_scene* scene = NULL;
    CHECK(palp_scene_make_deformable(volume, NAN, &o, &scene) == PALP_ERROR_INVALID_ARGUMENT);
    CHECK(strstr(palp_last_error(), "palp_deformable_options.youngs_modulus") != NULL);
    CHECK(scene == NULL);
    /* No support face and no bone: nothing holds the body. */
    palp_deformable_options_default(&o);
    o.support_face = PALP_FACE_NONE;
    o.bone_threshold = INFINITY;
    CHECK(palp_scene_make_deformable(volume, NAN, &o, &scene) == PALP_ERROR_INVALID_ARGUMENT);
    CHECK(strstr(palp_last_error(), "palp_scene_make_deformable") != NULL);
    CHECK(scene == NULL);
    palp_volume_release(volume);
}

/* PALP_FEM_AUTO (the default) keeps the whole mesh on a phantom-sized body, and says why. */
static void test_auto_keeps_the_whole_mesh(void) {
    palp_volume* volume = NULL;
    CHECK(palp_volume_make_phantom("bone", 0, NULL, 2e-3, &volume) == PALP_OK);
    palp_deformable_options o;
    palp_deformable_options_default(&o);
    CHECK(o.solver == PALP_FEM_AUTO);
    palp_scene* scene = NULL;
    CHECK(palp_scene_make_deformable(volume, NAN, &o, &scene) == PALP_OK);
    palp_solver_choice c;
    CHECK(palp_scene_solver(scene, &c) == PALP_OK);
    CHECK(c.solver == PALP_FEM_WHOLE_MESH && c.chosen == 1 && c.lod == 0);
    CHECK(c.element_substeps > 0 && c.element_substeps <= c.budget);
    CHECK(strncmp(c.reason, "whole mesh: ", 12) == 0 && strstr(c.reason, "within") != NULL);
    printf("bone phantom, auto: %s\n", c.reason);
    palp_scene_release(scene);
    palp_volume_release(volume);
}

/* Live: the servo thread steps the tissue while this (viewer) thread reads snapshots and the
 * deformed surface; the ticks the surface shows only go forward and its values stay finite. */
static void test_live_surface(void) {
    double centre[3];
    palp_scene* scene = make_scene(PALP_FEM_WHOLE_MESH, centre);
    if (!scene) return;
    size_t nv = 0;
    CHECK(palp_scene_surface_size(scene, &nv, NULL) == PALP_OK);
    float* now = malloc(3 * nv * sizeof *now);
    if (!now) abort();
    palp_session_params params;
    palp_trajectory path;
    make_session_inputs(centre, &params, &path);
    path.press_seconds = 0.2;
    palp_session* session = NULL;
    CHECK(palp_session_create_simulated(scene, &params, &path, &session) == PALP_OK);
    if (!session) return;
    CHECK(palp_session_start(session) == PALP_OK);
    uint64_t last = 0;
    int reads = 0, backwards = 0, nonFinite = 0;
    palp_snapshot s;
    do {
        uint64_t tick = 0;
        CHECK(palp_session_latest_surface(session, now, nv, &tick) == PALP_OK);
        CHECK(palp_session_latest(session, &s) == PALP_OK);
        if (tick < last) ++backwards;
        last = tick;
        for (size_t i = 0; i < 3 * nv; ++i) nonFinite += isfinite(now[i]) ? 0 : 1;
        ++reads;
    } while (s.tick < 300);
    CHECK(palp_session_stop(session) == PALP_OK);
    CHECK(backwards == 0 && nonFinite == 0 && reads > 1 && last > 0);
    palp_session_release(session);
    palp_scene_release(scene);
    free(now);
}

int main(void) {
    test_refusals();
    test_auto_keeps_the_whole_mesh();
#if defined(__SANITIZE_THREAD__)
    /* Offline steps on this thread only: no thread of palp's to race. The release suite and the
     * AddressSanitizer run check its physics; under ThreadSanitizer its 2,000 steps as fast as
     * they go would be most of this executable's time (the live case runs at 1 kHz). */
    (void)test_press_and_surface;
#else
    test_press_and_surface();
#endif
    test_live_surface();
    if (gFailures) fprintf(stderr, "%d check(s) failed\n", gFailures);
    return gFailures ? 1 : 0;
}
