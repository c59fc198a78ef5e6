/* The C API compiled as C11: handles, errors, and a VC press into the AVC phantom whose force
 * must point out of the surface with magnitude k D. Returns non-zero on the first failure. */
#include <math.h>
#include <stdio.h>
#include <string.h>
#include <unistd.h>

#include "c_check.h"
#include "palp/palp.h"
#include "palp/palp_study.h"

typedef struct callback_log {
    int calls;
    palp_status last;
    char message[512];
} callback_log;

static void on_error(void* user, palp_status status, const char* message) {
    callback_log* log = (callback_log*)user;
    ++log->calls;
    log->last = status;
    strncpy(log->message, message, sizeof log->message - 1);
    log->message[sizeof log->message - 1] = '\0';
}

static double norm3(const double v[3]) { return sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]); }

static void test_errors(void) {
    callback_log log;
    memset(&log, 0, sizeof log);
    palp_set_error_callback(on_error, &log);

    palp_volume* volume = NULL;
    const char* missing = "/nonexistent/palp-test/scan.nii.gz";
    CHECK(palp_volume_load(missing, 0.0, &volume) == PALP_ERROR_IO);
    CHECK(volume == NULL);
    CHECK(strstr(palp_last_error(), missing) != NULL);
    CHECK(log.calls == 1);
    CHECK(log.last == PALP_ERROR_IO);
    CHECK(strcmp(log.message, palp_last_error()) == 0);

    CHECK(palp_volume_make_phantom("no-such-scene", 0, NULL, 1e-3, &volume) ==
          PALP_ERROR_INVALID_ARGUMENT);
    CHECK(strstr(palp_last_error(), "no-such-scene") != NULL);
    CHECK(palp_volume_make_phantom("avc", 0, NULL, -1.0, &volume) == PALP_ERROR_INVALID_ARGUMENT);
    CHECK(palp_volume_load(NULL, 0.0, &volume) == PALP_ERROR_INVALID_ARGUMENT);
    CHECK(log.calls == 4);
    /* palp_study.h is plain C too: a study file that does not exist is named. */
    palp_study* study = NULL;
    CHECK(palp_study_open("/nonexistent/palp-test/study.json", "/nonexistent/palp-test/log.csv",
                          0, 0, &study) == PALP_ERROR_IO);
    CHECK(study == NULL);
    CHECK(strstr(palp_last_error(), "/nonexistent/palp-test/study.json") != NULL);
    CHECK(palp_study_finished(NULL) == 0);
    CHECK(log.calls == 5);

    palp_scene* scene = NULL;
    CHECK(palp_scene_create_empty(&scene) == PALP_OK);
    palp_session_params params;
    palp_session_params_default(&params);
    palp_trajectory path;
    CHECK(palp_trajectory_default(PALP_TRAJECTORY_PRESS, &path) == PALP_OK);
    palp_session* session = NULL;
    params.device = "Unknown Haptic Thing";
    CHECK(palp_session_create_simulated(scene, &params, &path, &session) ==
          PALP_ERROR_INVALID_ARGUMENT);
    CHECK(strstr(palp_last_error(), "Unknown Haptic Thing") != NULL);
    palp_session_params_default(&params);
    /* AVCEC with a volume source needs a volume: the empty scene has none. */
    CHECK(palp_session_create_simulated(scene, &params, &path, &session) ==
          PALP_ERROR_INVALID_ARGUMENT);
    params.mode = PALP_MODE_VC;
    params.stiffness = -5;
    CHECK(palp_session_create_simulated(scene, &params, &path, &session) ==
          PALP_ERROR_INVALID_ARGUMENT);
    CHECK(strstr(palp_last_error(), "baseStiffness") != NULL ||
          strstr(palp_last_error(), "stiffness") != NULL);
    CHECK(session == NULL);

    /* The empty scene works in VC: nothing to touch, no force. */
    params.stiffness = 300;
    CHECK(palp_session_create_simulated(scene, &params, &path, &session) == PALP_OK);
    palp_snapshot s;
    CHECK(palp_session_step(session, 500, &s) == PALP_OK);
    CHECK(s.tick == 499);
    CHECK(norm3(s.force) == 0.0);
    CHECK(palp_session_running(session) == 0);
    palp_session_release(session);
    palp_scene_release(scene);

    palp_set_error_callback(NULL, NULL);
    const int before = log.calls;
    CHECK(palp_volume_load(missing, 0.0, &volume) == PALP_ERROR_IO);
    CHECK(log.calls == before); /* cleared */
}

static void test_press(void) {
    palp_volume* volume = NULL;
    CHECK(palp_volume_make_phantom("avc", 0, NULL, 1e-3, &volume) == PALP_OK);
    if (!volume) return;
    double voxel = 0, lo[3], hi[3];
    CHECK(palp_volume_geometry(volume, &voxel, lo, hi) == PALP_OK);
    CHECK(fabs(voxel - 1e-3) < 1e-12);
    CHECK(fabs(lo[1]) < 1e-3 && hi[1] > 0.04); /* active voxels: depth 0..50 mm */

    palp_scene* scene = NULL;
    CHECK(palp_scene_from_volume(volume, -500.0, 500.0, &scene) == PALP_OK);
    palp_volume_release(volume); /* the scene keeps what it needs */
    if (!scene) return;

    palp_session_params params;
    palp_session_params_default(&params);
    params.mode = PALP_MODE_VC;
    params.stiffness = 300;
    params.static_friction = 0;
    params.dynamic_friction = 0;
    params.trace_capacity = 4096;
    palp_trajectory path;
    CHECK(palp_trajectory_default(PALP_TRAJECTORY_PRESS, &path) == PALP_OK);
    path.centre[0] = 0.002;
    path.centre[1] = -0.005; /* 5 mm above the skin */
    path.centre[2] = 0.001;
    path.direction[0] = 0;
    path.direction[1] = 1; /* into the surface (+y) */
    path.direction[2] = 0;
    path.depth = 0.009; /* target 4 mm deep */
    path.press_seconds = 0.4;
    path.hold_seconds = 1.0;

    palp_session* session = NULL;
    CHECK(palp_session_create_simulated(scene, &params, &path, &session) == PALP_OK);
    if (!session) {
        palp_scene_release(scene);
        return;
    }
    palp_snapshot s;
    CHECK(palp_session_step(session, 1000, &s) == PALP_OK); /* 0.6 s into the hold */
    CHECK(s.gate_open);
    CHECK(s.contact_count == 1);
    CHECK(s.mode == PALP_MODE_VC);
    CHECK(fabs(s.proxy[1]) < 0.5e-3);      /* the proxy on the skin */
    CHECK(s.probe[1] > s.proxy[1] + 1e-3); /* the probe more than 1 mm inside */
    CHECK(s.force[1] < 0);                 /* out of the surface (-y) */
    CHECK(fabs(s.force[0]) < 1e-3 * norm3(s.force) + 1e-9);
    CHECK(fabs(s.force[2]) < 1e-3 * norm3(s.force) + 1e-9);
    CHECK(fabs(s.distance - norm3((double[3]){s.probe[0] - s.proxy[0], s.probe[1] - s.proxy[1],
                                              s.probe[2] - s.proxy[2]})) < 1e-12);
    CHECK(fabs(norm3(s.force) - 300.0 * s.distance) < 1e-9); /* |F| = k D */
    CHECK(s.stiffness == 300.0);
    CHECK(s.observer_energy > 0); /* a pressed spring has absorbed energy */

    /* Every tick went to the trace, in order. */
    palp_snapshot t;
    int got = 0;
    uint64_t count = 0, expected = 0;
    for (;;) {
        CHECK(palp_session_pop_trace(session, &t, &got) == PALP_OK);
        if (!got) break;
        CHECK(t.tick == expected);
        ++expected;
        ++count;
    }
    CHECK(count == 1000);

    /* Run-time change: AVCEC (validated, queued, cross-faded) and back; the force stays
     * within the device limit at every tick. */
    CHECK(palp_session_set_mode(session, PALP_MODE_AVCEC) == PALP_OK);
    palp_session_params now;
    CHECK(palp_session_get_params(session, &now) == PALP_OK);
    CHECK(now.mode == PALP_MODE_AVCEC);
    now.period = 2e-3;
    CHECK(palp_session_set_params(session, &now) == PALP_ERROR_INVALID_ARGUMENT);
    CHECK(strstr(palp_last_error(), "period") != NULL);
    now.period = params.period;
    now.ray_length = -1;
    CHECK(palp_session_set_params(session, &now) == PALP_ERROR_INVALID_ARGUMENT);
    for (int i = 0; i < 300; ++i) {
        CHECK(palp_session_step(session, 1, &s) == PALP_OK);
        CHECK(isfinite(s.force[0]) && isfinite(s.force[1]) && isfinite(s.force[2]));
        CHECK(norm3(s.force) <= 7.9 + 1e-9); /* 3D Systems Touch X */
    }
    CHECK(s.mode == PALP_MODE_AVCEC);
    CHECK(s.rays >= 17);

    /* Real time for a short moment. */
    CHECK(palp_session_start(session) == PALP_OK);
    CHECK(palp_session_running(session) == 1);
    CHECK(palp_session_start(session) == PALP_ERROR_STATE);
    CHECK(palp_session_step(session, 1, &s) == PALP_ERROR_STATE);
    CHECK(palp_session_latest(session, &s) == PALP_OK);
    CHECK(strlen(palp_session_realtime_status(session)) > 0);
    CHECK(palp_session_stop(session) == PALP_OK);
    CHECK(palp_session_running(session) == 0);
    palp_loop_stats stats;
    CHECK(palp_session_stats(session, &stats) == PALP_OK);
    palp_realtime rt;
    CHECK(palp_session_realtime(session, &rt) == PALP_OK);
    CHECK(rt.message != NULL && strlen(rt.message) > 0);
    /* The servo's CPU was reserved (the default) when the process may use another one. */
    CHECK(params.servo_reserve_cpu == 1);
    if (rt.pinned && sysconf(_SC_NPROCESSORS_ONLN) > 1)
        CHECK(strstr(rt.message, "other threads moved off it") != NULL);
    /* Fixed at creation: a set call that changes it is refused by name. */
    CHECK(palp_session_get_params(session, &now) == PALP_OK);
    now.servo_reserve_cpu = 0;
    CHECK(palp_session_set_params(session, &now) == PALP_ERROR_INVALID_ARGUMENT);
    CHECK(strstr(palp_last_error(), "servo_reserve_cpu") != NULL);

    /* servo_reserve_cpu 0: the other threads keep the servo's CPU. */
    palp_session_params sharedCpu = params;
    sharedCpu.servo_reserve_cpu = 0;
    palp_session* sharing = NULL;
    CHECK(palp_session_create_simulated(scene, &sharedCpu, &path, &sharing) == PALP_OK);
    if (sharing) {
        CHECK(palp_session_start(sharing) == PALP_OK);
        CHECK(palp_session_stop(sharing) == PALP_OK);
        CHECK(palp_session_realtime(sharing, &rt) == PALP_OK);
        CHECK(rt.message != NULL && strstr(rt.message, "moved off") == NULL);
        palp_session_release(sharing);
    }

    /* Reference counts: the session outlives its creator's scene reference. */
    palp_session* again = palp_session_retain(session);
    CHECK(again == session);
    palp_session_release(session);
    palp_scene_release(scene);
    CHECK(palp_session_step(again, 10, &s) == PALP_OK);
    palp_session_release(again);
}

/* A VC session on @p scene (the AVC phantom) whose hand presses 4 mm into the skin and holds:
 * after 600 ticks the proxy is in contact and the snapshot's stiffness is k. */
static palp_session* pressed_session(palp_scene* scene, const palp_session_params* params) {
    palp_trajectory path;
    CHECK(palp_trajectory_default(PALP_TRAJECTORY_PRESS, &path) == PALP_OK);
    path.centre[0] = 0.002;
    path.centre[1] = -0.005;
    path.centre[2] = 0.001;
    path.direction[0] = 0;
    path.direction[1] = 1;
    path.direction[2] = 0;
    path.depth = 0.009;
    path.press_seconds = 0.4;
    path.hold_seconds = 10.0;
    palp_session* session = NULL;
    CHECK(palp_session_create_simulated(scene, params, &path, &session) == PALP_OK);
    palp_snapshot s;
    if (session) CHECK(palp_session_step(session, 600, &s) == PALP_OK);
    if (session) CHECK(s.contact_count == 1);
    return session;
}

/* palp_session_set_params is all or nothing: with one free slot in the command queue the
 * coupling, friction and passivity changes all go through (one command); with none, nothing
 * changes (neither get_params nor what the servo renders). */
static void test_set_params_all_or_nothing(palp_scene* scene) {
    palp_session_params params;
    palp_session_params_default(&params);
    params.mode = PALP_MODE_VC;
    params.stiffness = 300;
    params.static_friction = 0;
    params.dynamic_friction = 0;
    params.cross_fade_seconds = 0; /* a coupling change shows on the next tick */
    palp_session* session = pressed_session(scene, &params);
    if (!session) return;
    palp_snapshot s;
    CHECK(palp_session_step(session, 1, &s) == PALP_OK);
    CHECK(s.stiffness == 300.0);

    /* Fill the queue (nothing drains it while no tick runs). */
    int queued = 0;
    while (queued < 1000 && palp_session_reset_observer(session) == PALP_OK) ++queued;
    CHECK(queued > 1 && queued < 1000);
    palp_session_params change = params;
    change.stiffness = 500;
    change.static_friction = 0.4;
    change.dynamic_friction = 0.2;
    change.passivity_control = 1;
    CHECK(palp_session_set_params(session, &change) == PALP_ERROR_QUEUE_FULL);
    palp_session_params now;
    CHECK(palp_session_get_params(session, &now) == PALP_OK);
    CHECK(now.stiffness == 300.0 && now.static_friction == params.static_friction &&
          now.passivity_control == params.passivity_control);
    CHECK(palp_session_step(session, 1, &s) == PALP_OK); /* drains the queue */
    CHECK(s.stiffness == 300.0);

    /* One free slot: the whole change fits. */
    for (int i = 0; i < queued - 1; ++i) CHECK(palp_session_reset_observer(session) == PALP_OK);
    CHECK(palp_session_set_params(session, &change) == PALP_OK);
    CHECK(palp_session_get_params(session, &now) == PALP_OK);
    CHECK(now.stiffness == 500.0 && now.static_friction == 0.4 && now.dynamic_friction == 0.2 &&
          now.passivity_control == 1);
    CHECK(palp_session_set_params(session, &params) == PALP_ERROR_QUEUE_FULL); /* full again */
    CHECK(palp_session_get_params(session, &now) == PALP_OK);
    CHECK(now.stiffness == 500.0 && now.static_friction == 0.4);
    CHECK(palp_session_step(session, 1, &s) == PALP_OK);
    CHECK(s.stiffness == 500.0);

    /* An invalid field anywhere leaves everything as it was. */
    palp_session_params bad = change;
    bad.stiffness = 700;
    bad.dynamic_friction = 0.9; /* > static_friction */
    CHECK(palp_session_set_params(session, &bad) == PALP_ERROR_INVALID_ARGUMENT);
    CHECK(palp_session_get_params(session, &now) == PALP_OK);
    CHECK(now.stiffness == 500.0 && now.dynamic_friction == 0.2);
    CHECK(palp_session_step(session, 1, &s) == PALP_OK);
    CHECK(s.stiffness == 500.0);
    palp_session_release(session);
}

/* Stiffness above the device's maximum (3D Systems Touch X: 1480 N/m) is lowered to it at
 * creation and by set_params, reported in get_params and on the snapshot. */
static void test_stiffness_limit(palp_scene* scene) {
    palp_session_params params;
    palp_session_params_default(&params);
    params.mode = PALP_MODE_VC;
    params.stiffness = 2000;
    params.max_stiffness = 2400;
    params.cross_fade_seconds = 0;
    palp_session* session = pressed_session(scene, &params);
    if (!session) return;
    palp_session_params now;
    CHECK(palp_session_get_params(session, &now) == PALP_OK);
    CHECK(now.max_stiffness == 1480.0 && now.stiffness == 1480.0);
    palp_snapshot s;
    CHECK(palp_session_step(session, 1, &s) == PALP_OK);
    CHECK(s.stiffness == 1480.0);
    CHECK(s.stiffness_limited == 1);
    now.stiffness = 400;
    CHECK(palp_session_set_params(session, &now) == PALP_OK);
    CHECK(palp_session_step(session, 1, &s) == PALP_OK);
    CHECK(s.stiffness == 400.0);
    CHECK(s.stiffness_limited == 0);
    now.max_stiffness = 5000;
    CHECK(palp_session_set_params(session, &now) == PALP_OK);
    CHECK(palp_session_get_params(session, &now) == PALP_OK);
    CHECK(now.max_stiffness == 1480.0 && now.stiffness == 400.0);
    CHECK(palp_session_step(session, 1, &s) == PALP_OK);
    CHECK(s.stiffness_limited == 1);
    palp_session_release(session);
}

/* Every trajectory kind's defaults make a working session, and a bad field of each kind is
 * reported by name (the C <-> C++ conversion tables). */
static void test_trajectory_kinds(void) {
    palp_scene* scene = NULL;
    CHECK(palp_scene_create_empty(&scene) == PALP_OK);
    palp_session_params params;
    palp_session_params_default(&params);
    params.mode = PALP_MODE_VC;
    const palp_trajectory_kind kinds[5] = {PALP_TRAJECTORY_PRESS, PALP_TRAJECTORY_SWEEP,
                                           PALP_TRAJECTORY_RASTER, PALP_TRAJECTORY_CIRCLE,
                                           PALP_TRAJECTORY_SINUSOID};
    const char* bad_field[5] = {"press_seconds", "turn_seconds", "line_spacing", "approach_seconds",
                                "grow_seconds"};
    for (int k = 0; k < 5; ++k) {
        palp_trajectory path;
        CHECK(palp_trajectory_default(kinds[k], &path) == PALP_OK);
        CHECK(path.kind == kinds[k]);
        CHECK(path.hand_mass > 0);
        palp_session* session = NULL;
        CHECK(palp_session_create_simulated(scene, &params, &path, &session) == PALP_OK);
        palp_snapshot s;
        CHECK(palp_session_step(session, 200, &s) == PALP_OK);
        CHECK(isfinite(s.probe[0]) && isfinite(s.probe[1]) && isfinite(s.probe[2]));
        palp_session_release(session);
        session = NULL;

        if (k == 4) {
            path.grow_seconds = -1;
        } else if (k == 0) {
            path.press_seconds = 0;
        } else if (k == 1) {
            path.turn_seconds = 0;
        } else if (k == 2) {
            path.line_spacing = 0;
        } else {
            path.approach_seconds = 0;
        }
        CHECK(palp_session_create_simulated(scene, &params, &path, &session) ==
              PALP_ERROR_INVALID_ARGUMENT);
        CHECK(strstr(palp_last_error(), bad_field[k]) != NULL);
        CHECK(session == NULL);
        CHECK(palp_trajectory_default(kinds[k], &path) == PALP_OK);
        path.press_direction[0] = path.press_direction[1] = path.press_direction[2] = 0;
        path.direction[0] = path.direction[1] = path.direction[2] = 0;
        CHECK(palp_session_create_simulated(scene, &params, &path, &session) ==
              PALP_ERROR_INVALID_ARGUMENT);
        CHECK(strstr(palp_last_error(), "direction") != NULL);
    }
    palp_trajectory path;
    CHECK(palp_trajectory_default((palp_trajectory_kind)9, &path) == PALP_ERROR_INVALID_ARGUMENT);
    palp_scene_release(scene);
}

int main(void) {
    CHECK(strcmp(palp_version(), "0.1.0") == 0);
    CHECK(strcmp(palp_status_string(PALP_ERROR_IO), "PALP_ERROR_IO") == 0);
    CHECK(strcmp(palp_last_error(), "") == 0);
    test_errors();
    test_press();
    palp_volume* volume = NULL;
    CHECK(palp_volume_make_phantom("avc", 0, NULL, 1e-3, &volume) == PALP_OK);
    palp_scene* scene = NULL;
    if (volume) CHECK(palp_scene_from_volume(volume, -500.0, 500.0, &scene) == PALP_OK);
    palp_volume_release(volume);
    if (scene) {
        test_set_params_all_or_nothing(scene);
        test_stiffness_limit(scene);
    }
    palp_scene_release(scene);
    test_trajectory_kinds();
    if (gFailures)
        fprintf(stderr, "test_c_api: %d failure(s)\n", gFailures);
    else
        printf("test_c_api: all checks passed\n");
    return gFailures ? 1 : 0;
}
