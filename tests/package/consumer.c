/* A C program on palp's installed C API (tools/test_package.sh builds it with CMake and with
 * pkg-config): a scan read from a file (an NRRD it writes), then the AVC phantom -> a scene -> a
 * simulated VC press held 4 mm deep, stepped offline for 1000 ticks; the force must push out of
 * the skin with |F| = k D. Exits non-zero, saying why, on any failure. */
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "palp/palp.h"

static int failures = 0;

#define EXPECT(cond)                                                                       \
    do {                                                                                   \
        if (!(cond)) {                                                                     \
            fprintf(stderr, "consumer_c: %s:%d: failed: %s\n", __FILE__, __LINE__, #cond); \
            ++failures;                                                                    \
        }                                                                                  \
    } while (0)

static int ok(palp_status status, const char* what) {
    if (status == PALP_OK) return 1;
    fprintf(stderr, "consumer_c: %s: %s: %s\n", what, palp_status_string(status),
            palp_last_error());
    ++failures;
    return 0;
}

/* Writes an 8 x 8 x 8 int16 NRRD (1 mm voxels, LPS origin (10, -20, 30) mm, 100 HU everywhere)
 * and reads it with palp_volume_load: 1 mm voxels, the box of the voxel centres (7 mm) plus at
 * most the resampler's one-voxel border, centred where the header puts it. */
static void read_a_scan(void) {
    const char* dir = getenv("TMPDIR");
    char path[512];
    int local = 0;
    snprintf(path, sizeof path, "%s/palp_consumer_%lx_%lx.nrrd", dir && *dir ? dir : "/tmp",
             (unsigned long)time(NULL), (unsigned long)(uintptr_t)&local);
    FILE* f = fopen(path, "wb");
    EXPECT(f != NULL);
    if (!f) return;
    fprintf(f,
            "NRRD0004\ntype: short\ndimension: 3\nspace: left-posterior-superior\n"
            "sizes: 8 8 8\nspace directions: (1,0,0) (0,1,0) (0,0,1)\n"
            "space origin: (10,-20,30)\nendian: little\nencoding: raw\n\n");
    for (int i = 0; i < 8 * 8 * 8; ++i) {
        const unsigned char hu[2] = {100, 0}; /* 100, little-endian */
        fwrite(hu, 1, 2, f);
    }
    fclose(f);
    palp_volume* scan = NULL;
    if (ok(palp_volume_load(path, 0.0, &scan), "palp_volume_load")) {
        double size = 0, lo[3], hi[3];
        EXPECT(palp_volume_geometry(scan, &size, lo, hi) == PALP_OK);
        EXPECT(fabs(size - 1e-3) < 1e-12);
        const double centre[3] = {0.0135, -0.0165, 0.0335}; /* origin + 3.5 mm, in m */
        for (int a = 0; a < 3; ++a) {
            EXPECT(fabs(0.5 * (lo[a] + hi[a]) - centre[a]) < 1e-9);
            EXPECT(hi[a] - lo[a] > 7e-3 - 1e-9 && hi[a] - lo[a] < 9e-3 + 1e-9);
        }
        printf("consumer_c: read %s: %.1f mm voxels, x from %.1f to %.1f mm\n", path, size * 1e3,
               lo[0] * 1e3, hi[0] * 1e3);
        palp_volume_release(scan);
    }
    remove(path);
    /* A file that is not there: an I/O error naming it. */
    palp_volume* none = NULL;
    EXPECT(palp_volume_load(path, 0.0, &none) == PALP_ERROR_IO && none == NULL);
    EXPECT(strstr(palp_last_error(), path) != NULL);
}

int main(void) {
    /* The library is the one the header describes. */
    char header_version[32];
    snprintf(header_version, sizeof header_version, "%d.%d.%d", PALP_VERSION_MAJOR,
             PALP_VERSION_MINOR, PALP_VERSION_PATCH);
    EXPECT(strcmp(palp_version(), header_version) == 0);

    read_a_scan();

    palp_volume* volume = NULL;
    if (!ok(palp_volume_make_phantom("avc", 0, NULL, 1e-3, &volume), "phantom")) return 1;
    palp_scene* scene = NULL;
    const int built = ok(palp_scene_from_volume(volume, -500.0, 500.0, &scene), "scene");
    palp_volume_release(volume);
    if (!built) return 1;

    palp_session_params params;
    palp_session_params_default(&params);
    params.mode = PALP_MODE_VC;
    params.stiffness = 300;
    params.static_friction = 0;
    params.dynamic_friction = 0;
    palp_trajectory path;
    palp_trajectory_default(PALP_TRAJECTORY_PRESS, &path);
    path.centre[0] = 0.002;
    path.centre[1] = -0.005; /* 5 mm above the skin (y = 0, depth +y) */
    path.centre[2] = 0.001;
    path.direction[0] = 0;
    path.direction[1] = 1;
    path.direction[2] = 0;
    path.depth = 0.009; /* 4 mm into the skin */
    path.press_seconds = 0.4;
    path.hold_seconds = 1.0;
    palp_session* session = NULL;
    const int created =
        ok(palp_session_create_simulated(scene, &params, &path, &session), "session");
    /* Errors come back as statuses with palp's message naming the field. */
    palp_session_params bad = params;
    bad.device = "no such device";
    palp_session* refused = NULL;
    EXPECT(palp_session_create_simulated(scene, &bad, &path, &refused) ==
           PALP_ERROR_INVALID_ARGUMENT);
    EXPECT(refused == NULL && strstr(palp_last_error(), "no such device") != NULL);
    palp_scene_release(scene);
    if (!created) return 1;

    palp_snapshot s;
    memset(&s, 0, sizeof s);
    if (ok(palp_session_step(session, 1000, &s), "step")) { /* 0.6 s into the hold */
        const double f =
            sqrt(s.force[0] * s.force[0] + s.force[1] * s.force[1] + s.force[2] * s.force[2]);
        printf("consumer_c: palp %s, tick %llu: proxy y %.3f mm, probe y %.3f mm, force y %.4f N\n",
               palp_version(), (unsigned long long)s.tick, s.proxy[1] * 1e3, s.probe[1] * 1e3,
               s.force[1]);
        EXPECT(s.tick == 999);
        EXPECT(s.contact_count == 1);
        EXPECT(fabs(s.proxy[1]) < 0.5e-3);           /* the proxy on the skin */
        EXPECT(s.probe[1] > s.proxy[1] + 1e-3);      /* the probe more than 1 mm inside */
        EXPECT(s.force[1] < -0.3);                   /* out of the skin: at least 1 mm x 300 N/m */
        EXPECT(fabs(f - 300.0 * s.distance) < 1e-9); /* |F| = k D */
    }
    palp_session_release(session);
    if (failures) {
        fprintf(stderr, "consumer_c: %d failure(s)\n", failures);
        return 1;
    }
    printf("consumer_c: ok\n");
    return 0;
}
