/* A host device through the C API, compiled as C11: bad inputs are refused naming the field;
 * a kinematic press into the AVC phantom (VC, offline) feels k D out of the surface; the same
 * press on the servo thread for 200 ms; a host that stops answering gets zero force within
 * the watchdog time and its force comes back without a jump; a host volume from C. Returns non-zero
 * on the first failure. */
#define _POSIX_C_SOURCE 199309L /* nanosleep */
#include <math.h>
#include <stdio.h>
#include <string.h>
#include <time.h>

#include "c_check.h"
#include "palp/palp.h"

/* The host's device: a hand that moves from 3 mm above the surface (y = 0, facing -y) to
 * `depth` below it in 0.3 s at 1 kHz, then holds; `silent` stops its samples. */
typedef struct host_hand {
    uint64_t reads;
    int silent;
    double depth;
    double force[3];
    uint64_t writes;
} host_hand;

static double hand_y(const host_hand* h) {
    const double t = (double)h->reads * 1e-3;
    const double s = t < 0.3 ? t / 0.3 : 1.0;
    return -3e-3 + s * (3e-3 + h->depth);
}

static int read_hand(void* user, palp_device_state* state) {
    host_hand* h = (host_hand*)user;
    if (h->silent) return 1;
    ++h->reads;
    state->position[0] = 0.0;
    state->position[1] = hand_y(h);
    state->position[2] = 0.0;
    state->velocity[0] = state->velocity[2] = 0.0;
    state->velocity[1] = (double)h->reads * 1e-3 < 0.3 ? (3e-3 + h->depth) / 0.3 : 0.0;
    state->buttons = 0;
    state->sequence = h->reads;
    state->timestamp = (double)h->reads * 1e-3;
    return 0;
}

static void write_hand(void* user, const double force[3]) {
    host_hand* h = (host_hand*)user;
    memcpy(h->force, force, sizeof h->force);
    ++h->writes;
}

static double norm3(const double v[3]) { return sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]); }

static void test_bad_inputs(palp_scene* scene) {
    palp_session_params params;
    palp_session_params_default(&params);
    params.mode = PALP_MODE_VC;
    palp_device_callbacks cb;
    palp_device_callbacks_default(&cb);
    palp_session* session = NULL;

    CHECK(palp_session_create_host(scene, &params, &cb, &session) == PALP_ERROR_INVALID_ARGUMENT);
    CHECK(strstr(palp_last_error(), "read_state") != NULL);
    cb.read_state = read_hand;
    cb.spec.max_force = 0.0;
    CHECK(palp_session_create_host(scene, &params, &cb, &session) == PALP_ERROR_INVALID_ARGUMENT);
    CHECK(strstr(palp_last_error(), "palp_device_callbacks.spec.max_force") != NULL);
    palp_device_callbacks_default(&cb);
    cb.read_state = read_hand;
    cb.spec.workspace_max[1] = cb.spec.workspace_min[1] - 1e-3;
    CHECK(palp_session_create_host(scene, &params, &cb, &session) == PALP_ERROR_INVALID_ARGUMENT);
    CHECK(strstr(palp_last_error(), "spec.workspace_max[1]") != NULL);
    palp_device_callbacks_default(&cb);
    cb.read_state = read_hand;
    cb.watchdog_grace = cb.watchdog_timeout;
    CHECK(palp_session_create_host(scene, &params, &cb, &session) == PALP_ERROR_INVALID_ARGUMENT);
    CHECK(strstr(palp_last_error(), "graceSeconds") != NULL);
    cb.watchdog_grace = 0.0;
    cb.watchdog_timeout = NAN;
    CHECK(palp_session_create_host(scene, &params, &cb, &session) == PALP_ERROR_INVALID_ARGUMENT);
    CHECK(strstr(palp_last_error(), "timeoutSeconds") != NULL);
    CHECK(session == NULL);
    CHECK(palp_session_create_host(scene, &params, NULL, &session) == PALP_ERROR_INVALID_ARGUMENT);

    palp_device_spec spec;
    CHECK(palp_device_spec_from_class("No Such Arm", &spec) == PALP_ERROR_INVALID_ARGUMENT);
    CHECK(strstr(palp_last_error(), "palp_device_spec_from_class: device_class") != NULL);
    CHECK(strstr(palp_last_error(), "No Such Arm") != NULL);
    CHECK(palp_device_spec_from_class("3D Systems Touch", &spec) == PALP_OK);
    CHECK(fabs(spec.max_force - 3.3) < 1e-12);
}

/* Offline: the press, then silence, then samples again. */
static void test_press_and_watchdog(palp_scene* scene) {
    palp_session_params params;
    palp_session_params_default(&params);
    params.mode = PALP_MODE_VC;
    params.stiffness = 300.0;
    host_hand hand;
    memset(&hand, 0, sizeof hand);
    hand.depth = 2e-3;
    palp_device_callbacks cb;
    palp_device_callbacks_default(&cb);
    cb.read_state = read_hand;
    cb.write_force = write_hand;
    cb.user = &hand;
    cb.name = "test hand";
    palp_session* session = NULL;
    CHECK(palp_session_create_host(scene, &params, &cb, &session) == PALP_OK);
    if (!session) return;
    palp_session_params now;
    CHECK(palp_session_get_params(session, &now) == PALP_OK);
    CHECK(strcmp(now.device, "test hand") == 0);

    palp_snapshot s;
    CHECK(palp_session_step(session, 500, &s) == PALP_OK);
    /* VC: k D out of the surface (-y), D = the depth (the iso-surface within half a voxel). */
    CHECK(s.contact_count > 0);
    CHECK(s.force[1] < 0);
    CHECK(fabs(norm3(s.force) - 300.0 * 2e-3) < 0.1 * 300.0 * 2e-3);
    CHECK(fabs(hand.force[1] - s.force[1]) < 1e-12); /* identity workspace: sent as shown */
    CHECK(hand.writes == 500);
    CHECK(s.device_stale == 0 && s.device_force_scale == 1.0 && s.watchdog_trips == 0);
    const double held = norm3(s.force);

    /* Silence: whole for the 2 ms grace, zero by the 10 ms timeout. */
    hand.silent = 1;
    CHECK(palp_session_step(session, 2, &s) == PALP_OK);
    CHECK(s.device_stale == 1);
    CHECK(fabs(norm3(s.force) - held) < 1e-9);
    CHECK(palp_session_step(session, 8, &s) == PALP_OK);
    CHECK(norm3(s.force) == 0.0 && norm3(hand.force) == 0.0);
    CHECK(s.watchdog_trips == 1 && s.device_force_scale == 0.0);
    CHECK(palp_session_step(session, 40, &s) == PALP_OK);
    CHECK(norm3(hand.force) == 0.0 && s.watchdog_trips == 1);

    /* Samples again: the force climbs back over 50 ms, never by more than a step. */
    hand.silent = 0;
    double last = 0.0, maxStep = 0.0;
    for (int i = 0; i < 80; ++i) {
        CHECK(palp_session_step(session, 1, &s) == PALP_OK);
        const double f = norm3(s.force);
        if (fabs(f - last) > maxStep) maxStep = fabs(f - last);
        last = f;
    }
    CHECK(maxStep <= held / 50.0 * 1.05);
    CHECK(fabs(last - held) < 1e-6 * held);
    CHECK(s.device_stale == 0 && s.device_force_scale == 1.0 && s.watchdog_trips == 1);
    palp_session_release(session);
}

static void sleep_ms(long ms) {
    struct timespec t;
    t.tv_sec = ms / 1000;
    t.tv_nsec = (ms % 1000) * 1000000L;
    nanosleep(&t, NULL);
}

/* On the servo thread for 200 ms or more (reads are ticks: the same press, faster than real time
 * is impossible, so the hand reaches 2/3 of its way in 0.2 s). */
static void test_realtime(palp_scene* scene) {
    palp_session_params params;
    palp_session_params_default(&params);
    params.mode = PALP_MODE_VC;
    params.servo_priority = 0;
    host_hand hand;
    memset(&hand, 0, sizeof hand);
    hand.depth = 2e-3;
    palp_device_callbacks cb;
    palp_device_callbacks_default(&cb);
    cb.read_state = read_hand;
    cb.write_force = write_hand;
    cb.user = &hand;
    palp_session* session = NULL;
    CHECK(palp_session_create_host(scene, &params, &cb, &session) == PALP_OK);
    if (!session) return;
    CHECK(palp_session_start(session) == PALP_OK);
    /* At least 200 ms, then until 100 ticks have run: a loaded machine (a sanitizer build on two
     * cores) may start the servo thread late, and the count of ticks is what is checked, not
     * how fast they came (10 s at most). */
    palp_snapshot s;
    memset(&s, 0, sizeof s);
    sleep_ms(200);
    for (int waited = 200; waited < 10000; waited += 10) {
        CHECK(palp_session_latest(session, &s) == PALP_OK);
        if (s.tick > 100) break;
        sleep_ms(10);
    }
    CHECK(palp_session_stop(session) == PALP_OK);
    CHECK(palp_session_latest(session, &s) == PALP_OK);
    CHECK(s.tick > 100);
    /* The probe is where the host put it at its last read (identity workspace). */
    const double y = hand_y(&hand);
    CHECK(fabs(s.probe[1] - y) < 1e-12);
    if (y > 1e-4) { /* pressed in: k D out of the surface */
        CHECK(s.force[1] < 0);
        CHECK(fabs(norm3(s.force) - 300.0 * y) < 0.1 * 300.0 * y + 0.02);
    }
    palp_session_release(session);
}

/* A host's buffer as a volume, from C: an 8^3 float32 block (1 mm voxels, RAS mm) whose
 * world box is the affine's, and a stride that makes rows overlap refused naming it. */
static void test_volume_from_memory(void) {
    float block[8][8][8];
    for (int k = 0; k < 8; ++k)
        for (int j = 0; j < 8; ++j)
            for (int i = 0; i < 8; ++i) block[k][j][i] = (float)(10 * i + j - k);
    const int64_t dims[3] = {8, 8, 8};
    /* RAS mm, origin (5, 6, 7) mm: in LPS metres x and y flip sign. */
    const double ijk_to_ras[16] = {1, 0, 0, 5, 0, 1, 0, 6, 0, 0, 1, 7, 0, 0, 0, 1};
    palp_volume* volume = NULL;
    CHECK(palp_volume_from_memory(block, PALP_VALUE_F32, dims, NULL, ijk_to_ras, PALP_FRAME_RAS_MM,
                                  0.0, &volume) == PALP_OK);
    double size = 0, lo[3], hi[3];
    CHECK(palp_volume_geometry(volume, &size, lo, hi) == PALP_OK);
    CHECK(fabs(size - 1e-3) < 1e-12);
    { /* centred on the affine's centre, RAS (5 + 3.5, 6 + 3.5, 7 + 3.5) mm -> LPS, spanning the
       * 7 mm of voxel centres plus the resampler's one-voxel border on each side */
        const double centre[3] = {-0.0085, -0.0095, 0.0105};
        for (int a = 0; a < 3; ++a) {
            CHECK(fabs(0.5 * (lo[a] + hi[a]) - centre[a]) < 1e-9);
            CHECK(hi[a] - lo[a] > 7e-3 - 1e-9 && hi[a] - lo[a] < 9e-3 + 1e-9);
        }
    }
    palp_volume_release(volume);
    volume = NULL;
    const int64_t strides[3] = {4, 16, 256}; /* rows of 8 floats need 32 bytes */
    CHECK(palp_volume_from_memory(block, PALP_VALUE_F32, dims, strides, ijk_to_ras,
                                  PALP_FRAME_RAS_MM, 0.0, &volume) == PALP_ERROR_INVALID_ARGUMENT);
    CHECK(strstr(palp_last_error(), "strides[1]") != NULL);
    CHECK(volume == NULL);
}

int main(void) {
    palp_volume* volume = NULL;
    CHECK(palp_volume_make_phantom("avc", 0, NULL, 1e-3, &volume) == PALP_OK);
    palp_scene* scene = NULL;
    CHECK(palp_scene_from_volume(volume, -500.0, 500.0, &scene) == PALP_OK);
    palp_volume_release(volume);
    if (!scene) return 1;
    test_bad_inputs(scene);
    test_press_and_watchdog(scene);
    test_realtime(scene);
    test_volume_from_memory();
    palp_scene_release(scene);
    if (gFailures) fprintf(stderr, "%d failure(s)\n", gFailures);
    return gFailures ? 1 : 0;
}
