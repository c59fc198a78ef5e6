/* A viewer-style program on palp's C API: load a volume (or generate the AVC phantom), build a
 * scene, run a simulated hand over it on a raster path in real time, print snapshots and the
 * loop statistics, and release everything.
 *
 *   simulated_session [scan-or-vdb] [seconds]
 *
 * With no path, the AVC phantom (1 mm voxels) is used; seconds defaults to 1. Exits non-zero
 * on any error, printing palp's message. */
#define _POSIX_C_SOURCE 200809L /* nanosleep */

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <time.h>

#include "palp/palp.h"

static int failed(palp_status status, const char* what) {
    if (status == PALP_OK) return 0;
    fprintf(stderr, "simulated_session: error: %s: %s: %s\n", what, palp_status_string(status),
            palp_last_error());
    return 1;
}

static void sleep_ms(long ms) {
    struct timespec ts;
    ts.tv_sec = ms / 1000;
    ts.tv_nsec = (ms % 1000) * 1000000L;
    nanosleep(&ts, NULL);
}

static void print_latency(const char* name, const palp_latency* l) {
    printf("  %-13s p50 %7.1f us  p99 %7.1f us  p99.9 %7.1f us  max %7.1f us  (n = %llu)\n", name,
           l->p50 * 1e6, l->p99 * 1e6, l->p999 * 1e6, l->max * 1e6, (unsigned long long)l->count);
}

int main(int argc, char** argv) {
    const char* path = argc > 1 && argv[1][0] ? argv[1] : NULL; /* "" = phantom */
    const double seconds = argc > 2 ? atof(argv[2]) : 1.0;
    if (!(seconds > 0 && seconds < 3600)) {
        fprintf(stderr, "simulated_session: error: expected seconds in (0, 3600), found '%s'\n",
                argv[2]);
        return 2;
    }
    printf("palp %s\n", palp_version());

    palp_volume* volume = NULL;
    if (path) {
        if (failed(palp_volume_load(path, 0.0, &volume), "loading the volume")) return 1;
    } else if (failed(palp_volume_make_phantom("avc", 2, NULL, 1e-3, &volume),
                      "making the phantom")) {
        return 1;
    }
    double voxel = 0, lo[3], hi[3];
    palp_volume_geometry(volume, &voxel, lo, hi);
    printf("volume: %s, voxel %.3g mm, x %.1f..%.1f mm, y %.1f..%.1f mm, z %.1f..%.1f mm\n",
           path ? path : "AVC phantom (hidden box in quadrant 2)", voxel * 1e3, lo[0] * 1e3,
           hi[0] * 1e3, lo[1] * 1e3, hi[1] * 1e3, lo[2] * 1e3, hi[2] * 1e3);

    palp_scene* scene = NULL;
    palp_status st = palp_scene_from_volume(volume, -500.0, 500.0, &scene);
    palp_volume_release(volume);
    if (failed(st, "building the scene")) return 1;

    palp_session_params params;
    palp_session_params_default(&params);
    params.mode = PALP_MODE_AVCEC;
    params.source = PALP_SOURCE_VOLUME_FIRST_HIT;
    params.threshold = 300;         /* HU: rigid structures */
    params.reference_length = 0.03; /* stiffer where the hard structure is within 30 mm */
    params.ray_length = 0.04;
    params.max_stiffness = 1400; /* below the Touch X's 1480 N/m */
    params.servo_priority = 0;   /* ask for SCHED_FIFO with e.g. 80 (needs CAP_SYS_NICE) */

    /* A raster over the scene's top surface (y = min), pressing +y: the phantom's frame. The
     * device frame is the world frame here (identity workspace). */
    palp_trajectory raster;
    palp_trajectory_default(PALP_TRAJECTORY_RASTER, &raster);
    raster.centre[0] = 0.5 * (lo[0] + hi[0]);
    raster.centre[1] = path ? lo[1] : 0.0;
    raster.centre[2] = 0.5 * (lo[2] + hi[2]);
    raster.extent_u = 0.04;
    raster.extent_v = 0.04;
    raster.line_spacing = 0.005;
    raster.speed = 0.08;
    raster.approach_seconds = 0.2;

    palp_session* session = NULL;
    st = palp_session_create_simulated(scene, &params, &raster, &session);
    palp_scene_release(scene);
    if (failed(st, "creating the session")) return 1;

    if (failed(palp_session_start(session), "starting the servo loop")) {
        palp_session_release(session);
        return 1;
    }
    printf("servo thread: %s\n", palp_session_realtime_status(session));
    printf("%8s %8s %24s %24s %22s %9s %6s\n", "tick", "t [s]", "probe [mm]", "proxy [mm]",
           "force [N]", "k [N/m]", "W [mJ]");
    const long stepMs = 100;
    const long steps = (long)ceil(seconds * 1000.0 / (double)stepMs);
    for (long i = 0; i < steps; ++i) {
        sleep_ms(stepMs);
        palp_snapshot s;
        palp_session_latest(session, &s);
        printf(
            "%8llu %8.3f (%6.2f %6.2f %6.2f) (%6.2f %6.2f %6.2f) (%6.3f %6.3f %6.3f) %9.1f "
            "%6.3f%s%s\n",
            (unsigned long long)s.tick, s.time, s.probe[0] * 1e3, s.probe[1] * 1e3,
            s.probe[2] * 1e3, s.proxy[0] * 1e3, s.proxy[1] * 1e3, s.proxy[2] * 1e3, s.force[0],
            s.force[1], s.force[2], s.stiffness, s.observer_energy * 1e3,
            s.gate_open ? "" : " gate-closed", s.clamped ? " clamped" : "");
    }
    palp_session_stop(session);

    palp_loop_stats stats;
    palp_session_stats(session, &stats);
    palp_realtime rt;
    palp_session_realtime(session, &rt);
    printf("loop: %llu ticks, %llu deadline misses, %llu skipped\n",
           (unsigned long long)stats.ticks, (unsigned long long)stats.misses,
           (unsigned long long)stats.skipped);
    print_latency("wake latency", &stats.wake_latency);
    print_latency("period error", &stats.period_error);
    print_latency("compute", &stats.compute);
    printf("realtime: pinned %s (cpu %d), SCHED_FIFO %s, memory locked %s%s\n",
           rt.pinned ? "yes" : "no", rt.cpu, rt.fifo ? "yes" : "no",
           rt.memory_locked ? "yes" : "no", rt.failed ? " (a request was refused)" : "");

    palp_session_release(session);
    return stats.ticks > 0 ? 0 : 1;
}
