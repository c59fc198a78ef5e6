/* A remote device through the C API, compiled as C11: palp_session_create_udp on port 0 (the
 * system's choice, read back), driven by a UDP sender in this test that encodes the bridge's
 * State datagrams byte by byte from docs/device_bridge.md and decodes the Force datagrams.
 * Offline (one State, then one palp_session_step per tick): nothing is sent before the first
 * State; a press 3 mm into the AVC phantom (VC, k 300 N/m, no friction) is felt as k D out of
 * the skin in the snapshot and in the Force datagram, which echoes the State's sequence and
 * time, and the State's orientation is published for a viewer; a foreign datagram is ignored
 * and counted; when the States stop the force is cut within the watchdog's timeout. Then the
 * same press on the servo thread. Bad listen addresses and a port in use are refused naming
 * palp_udp_device_params.listen. Returns non-zero on the first failure. */
#define _POSIX_C_SOURCE 200112L /* sockets, nanosleep */
#include <arpa/inet.h>
#include <errno.h>
#include <math.h>
#include <netinet/in.h>
#include <stdint.h>
#include <stdio.h>
#include <string.h>
#include <sys/socket.h>
#include <sys/time.h>
#include <time.h>
#include <unistd.h>

#include "c_check.h"
#include "palp/palp.h"

/* --- the bridge protocol, little-endian, from docs/device_bridge.md ----------------------- */

static void put_u16(uint8_t* p, uint16_t v) {
    p[0] = (uint8_t)v;
    p[1] = (uint8_t)(v >> 8);
}
static void put_u64(uint8_t* p, uint64_t v) {
    for (int i = 0; i < 8; ++i) p[i] = (uint8_t)(v >> (8 * i));
}
static void put_f64(uint8_t* p, double v) {
    uint64_t bits;
    memcpy(&bits, &v, sizeof bits);
    put_u64(p, bits);
}
static uint16_t get_u16(const uint8_t* p) { return (uint16_t)(p[0] | (p[1] << 8)); }
static uint32_t get_u32(const uint8_t* p) {
    uint32_t v = 0;
    for (int i = 3; i >= 0; --i) v = (v << 8) | p[i];
    return v;
}
static uint64_t get_u64(const uint8_t* p) {
    uint64_t v = 0;
    for (int i = 7; i >= 0; --i) v = (v << 8) | p[i];
    return v;
}
static double get_f64(const uint8_t* p) {
    const uint64_t bits = get_u64(p);
    double v;
    memcpy(&v, &bits, sizeof v);
    return v;
}

enum { kStateBytes = 112, kForceBytes = 88 };

/* The remote device's orientation: 90 degrees about z (w, x, y, z). */
static const double kOrientation[4] = {0.7071067811865476, 0.0, 0.0, 0.7071067811865476};

/* A State: position (m, device frame), identity orientation, velocity, no buttons. */
static void encode_state(uint8_t out[kStateBytes], uint64_t sequence, uint64_t time_ns,
                         const double position[3], const double velocity[3]) {
    memset(out, 0, kStateBytes);
    memcpy(out, "PLPB", 4);
    put_u16(out + 4, 1);
    put_u16(out + 6, 1);
    put_u64(out + 8, sequence);
    put_u64(out + 16, time_ns);
    for (int i = 0; i < 3; ++i) put_f64(out + 24 + 8 * i, position[i]);
    put_f64(out + 48, kOrientation[0]); /* w, x, y, z */
    put_f64(out + 56, kOrientation[1]);
    put_f64(out + 64, kOrientation[2]);
    put_f64(out + 72, kOrientation[3]);
    for (int i = 0; i < 3; ++i) put_f64(out + 80 + 8 * i, velocity[i]);
}

typedef struct force_message {
    uint64_t sequence, tick, state_sequence, state_time_ns;
    double force[3], force_scale;
    uint32_t flags;
} force_message;

/* 1 when @p bytes is a Force of @p n bytes, decoded into @p f. */
static int decode_force(const uint8_t* bytes, long n, force_message* f) {
    if (n != kForceBytes || memcmp(bytes, "PLPB", 4) != 0 || get_u16(bytes + 4) != 1 ||
        get_u16(bytes + 6) != 2)
        return 0;
    f->sequence = get_u64(bytes + 8);
    for (int i = 0; i < 3; ++i) f->force[i] = get_f64(bytes + 24 + 8 * i);
    f->tick = get_u64(bytes + 48);
    f->state_sequence = get_u64(bytes + 56);
    f->state_time_ns = get_u64(bytes + 64);
    f->force_scale = get_f64(bytes + 72);
    f->flags = get_u32(bytes + 80);
    return 1;
}

/* --- the test's remote device ------------------------------------------------------------ */

/* A UDP socket connected to palp's port on loopback, with a receive timeout. */
static int open_sender(int port) {
    const int fd = socket(AF_INET, SOCK_DGRAM, 0);
    if (fd < 0) return -1;
    struct sockaddr_in to;
    memset(&to, 0, sizeof to);
    to.sin_family = AF_INET;
    to.sin_port = htons((uint16_t)port);
    to.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
    struct timeval timeout = {2, 0}; /* a loaded CI machine: generous */
    if (connect(fd, (const struct sockaddr*)&to, sizeof to) != 0 ||
        setsockopt(fd, SOL_SOCKET, SO_RCVTIMEO, &timeout, sizeof timeout) != 0) {
        close(fd);
        return -1;
    }
    return fd;
}

static int send_state(int fd, uint64_t sequence, double y, double vy) {
    uint8_t d[kStateBytes];
    const double p[3] = {0.004, y, 0.003}, v[3] = {0.0, vy, 0.0};
    encode_state(d, sequence, 1000000u * sequence, p, v);
    return send(fd, d, sizeof d, 0) == (long)sizeof d;
}

/* The next Force (waiting up to the socket's timeout when @p wait); 0 when none. */
static int receive_force(int fd, force_message* f, int wait) {
    uint8_t d[256];
    const long n = recv(fd, d, sizeof d, wait ? 0 : MSG_DONTWAIT);
    return n > 0 && decode_force(d, n, f);
}

static double norm3(const double v[3]) { return sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]); }

/* The press: from 4 mm above the skin (y = 0, facing -y) to 3 mm below it in 0.3 s, held. */
static double press_y(int tick) {
    const double s = tick < 300 ? tick / 300.0 : 1.0;
    return -4e-3 + s * 7e-3;
}

static void vc_params(palp_session_params* params) {
    palp_session_params_default(params);
    params->mode = PALP_MODE_VC;
    params->stiffness = 300.0;
    params->static_friction = 0.0;
    params->dynamic_friction = 0.0;
    params->servo_priority = 0;
}

static void test_bad_inputs(palp_scene* scene) {
    palp_session_params params;
    vc_params(&params);
    palp_udp_device_params dev;
    palp_udp_device_params_default(&dev);
    CHECK(strcmp(dev.listen, "127.0.0.1:7405") == 0);
    palp_session* session = NULL;
    dev.listen = "localhost7405";
    CHECK(palp_session_create_udp(scene, &params, &dev, &session) == PALP_ERROR_INVALID_ARGUMENT);
    CHECK(strstr(palp_last_error(), "palp_udp_device_params.listen 'localhost7405'") != NULL);
    dev.listen = NULL;
    CHECK(palp_session_create_udp(scene, &params, &dev, &session) == PALP_ERROR_INVALID_ARGUMENT);
    CHECK(strstr(palp_last_error(), "device->listen") != NULL);
    palp_udp_device_params_default(&dev);
    dev.listen = "127.0.0.1:0";
    dev.max_drain = 0;
    CHECK(palp_session_create_udp(scene, &params, &dev, &session) == PALP_ERROR_INVALID_ARGUMENT);
    CHECK(strstr(palp_last_error(), "palp_udp_device_params.max_drain") != NULL);
    palp_udp_device_params_default(&dev);
    dev.listen = "127.0.0.1:0";
    dev.watchdog_grace = dev.watchdog_timeout;
    CHECK(palp_session_create_udp(scene, &params, &dev, &session) == PALP_ERROR_INVALID_ARGUMENT);
    CHECK(strstr(palp_last_error(), "palp_udp_device_params.watchdog_timeout") != NULL);
    palp_udp_device_params_default(&dev);
    dev.listen = "127.0.0.1:0";
    dev.spec.max_force = -1.0;
    CHECK(palp_session_create_udp(scene, &params, &dev, &session) == PALP_ERROR_INVALID_ARGUMENT);
    CHECK(strstr(palp_last_error(), "palp_udp_device_params.spec.max_force") != NULL);
    CHECK(session == NULL);

    /* A port in use: the second session binds the first one's address. */
    palp_udp_device_params_default(&dev);
    dev.listen = "127.0.0.1:0";
    palp_session* first = NULL;
    CHECK(palp_session_create_udp(scene, &params, &dev, &first) == PALP_OK);
    if (!first) return;
    char address[64];
    snprintf(address, sizeof address, "127.0.0.1:%d", palp_session_udp_port(first));
    CHECK(strcmp(palp_session_udp_address(first), address) == 0);
    dev.listen = address;
    CHECK(palp_session_create_udp(scene, &params, &dev, &session) == PALP_ERROR_IO);
    CHECK(strstr(palp_last_error(), "palp_udp_device_params.listen") != NULL);
    CHECK(strstr(palp_last_error(), address) != NULL);
    CHECK(strstr(palp_last_error(), "EADDRINUSE") != NULL);
    palp_session_release(first);
}

/* Offline: one State, one tick, one Force, tick by tick. */
static void test_offline_press(palp_scene* scene) {
    palp_session_params params;
    vc_params(&params);
    palp_udp_device_params dev;
    palp_udp_device_params_default(&dev);
    dev.listen = "127.0.0.1:0";
    dev.name = "test remote";
    palp_session* session = NULL;
    CHECK(palp_session_create_udp(scene, &params, &dev, &session) == PALP_OK);
    if (!session) return;
    palp_session_params now;
    CHECK(palp_session_get_params(session, &now) == PALP_OK);
    CHECK(strcmp(now.device, "test remote") == 0);
    const int port = palp_session_udp_port(session);
    CHECK(port > 0);
    CHECK(palp_session_udp_port(NULL) == 0);
    const int fd = open_sender(port);
    CHECK(fd >= 0);
    if (fd < 0) {
        palp_session_release(session);
        return;
    }

    /* Before any State: at rest, stale, no force, nothing sent. */
    palp_snapshot s;
    force_message f;
    CHECK(palp_session_step(session, 5, &s) == PALP_OK);
    CHECK(s.device_stale == 1 && s.device_force_scale == 0.0 && norm3(s.force) == 0.0);
    CHECK(!receive_force(fd, &f, 0));

    /* The press: each tick reads the State sent just before it (loopback delivers at send). */
    const int ticks = 500;
    int answered = 0, echoed = 0, whole = 0;
    for (int i = 0; i < ticks; ++i) {
        const uint64_t seq = (uint64_t)i + 1;
        CHECK(send_state(fd, seq, press_y(i), i < 300 ? 7e-3 / 0.3 : 0.0));
        CHECK(palp_session_step(session, 1, &s) == PALP_OK);
        if (!receive_force(fd, &f, 1)) continue;
        ++answered;
        echoed += f.state_sequence == seq && f.state_time_ns == 1000000u * seq;
        /* The Force is the snapshot's (identity workspace: device frame = world). */
        whole += f.force_scale == 1.0 && f.flags == 0 && f.tick == s.tick &&
                 f.force[0] == s.force[0] && f.force[1] == s.force[1] && f.force[2] == s.force[2];
    }
    CHECK(answered == ticks);
    CHECK(echoed == ticks);
    CHECK(whole == ticks);
    /* VC without friction: the proxy rests on the skin (y = 0 within half a voxel), the force
     * is k D along -y, D = the 3 mm the probe lies under it. */
    CHECK(s.contact_count > 0);
    CHECK(fabs(s.probe[1] - 3e-3) < 1e-12);
    CHECK(fabs(s.proxy[1]) < 0.5e-3);
    CHECK(fabs(s.force[1] + 300.0 * (s.probe[1] - s.proxy[1])) < 1e-9);
    CHECK(fabs(norm3(s.force) - 0.9) < 0.15);
    CHECK(s.device_stale == 0 && s.device_force_scale == 1.0 && s.watchdog_trips == 0);
    const double held = norm3(s.force);
    /* What a snapshot lacks, published for a viewer: the newest State's orientation. */
    palp_udp_state state;
    CHECK(palp_session_udp_state(session, &state) == PALP_OK);
    CHECK(state.sequence == (uint64_t)ticks && state.time_ns == 1000000u * (uint64_t)ticks);
    for (int i = 0; i < 4; ++i) CHECK(state.orientation[i] == kOrientation[i]);
    CHECK(fabs(state.position[1] - 3e-3) < 1e-15 && state.buttons == 0);

    /* A foreign datagram: ignored and counted, the force unchanged. */
    CHECK(send(fd, "hello, palp", 11, 0) == 11);
    CHECK(send_state(fd, (uint64_t)ticks + 1, press_y(ticks), 0.0));
    CHECK(palp_session_step(session, 1, &s) == PALP_OK);
    CHECK(receive_force(fd, &f, 1));
    CHECK(fabs(norm3(f.force) - held) < 1e-9);
    palp_udp_device_counters c;
    CHECK(palp_session_udp_counters(session, &c) == PALP_OK);
    CHECK(c.received == (uint64_t)ticks + 1);
    CHECK(c.lost == 0 && c.late == 0 && c.superseded == 0);
    CHECK(c.ignored == 1 && c.bad_magic == 1);
    CHECK(c.forces_sent == (uint64_t)ticks + 1 && c.forces_send_failed == 0);

    /* The States stop: whole for the 2 ms grace, zero by the 10 ms timeout; the Forces keep
     * coming, flagged stale and then cut (bit 2). */
    CHECK(palp_session_step(session, 2, &s) == PALP_OK);
    CHECK(s.device_stale == 1 && fabs(norm3(s.force) - held) < 1e-9);
    CHECK(palp_session_step(session, 8, &s) == PALP_OK);
    CHECK(norm3(s.force) == 0.0 && s.device_force_scale == 0.0 && s.watchdog_trips == 1);
    force_message last;
    memset(&last, 0, sizeof last);
    int stale = 0;
    while (receive_force(fd, &f, 0)) {
        last = f;
        stale += (f.flags & 1u) != 0;
    }
    CHECK(stale == 10);
    CHECK(norm3(last.force) == 0.0 && last.force_scale == 0.0 && (last.flags & 4u) != 0);
    close(fd);
    palp_session_release(session);
}

static void sleep_ms(long ms) {
    struct timespec t;
    t.tv_sec = ms / 1000;
    t.tv_nsec = (ms % 1000) * 1000000L;
    nanosleep(&t, NULL);
}

/* On the servo thread: this thread sends the press at about 1 kHz for 0.5 s and reads the
 * Forces back. The watchdog is 0.5 s (grace 0.4 s) so that a test thread starved of CPU on a
 * loaded machine does not scale the force; the Forces are checked against the State each
 * echoes (k D of that State's depth), whatever tick they belong to. */
static void test_realtime_press(palp_scene* scene) {
    palp_session_params params;
    vc_params(&params);
    palp_udp_device_params dev;
    palp_udp_device_params_default(&dev);
    dev.listen = "127.0.0.1:0";
    dev.watchdog_timeout = 0.5;
    dev.watchdog_grace = 0.4;
    palp_session* session = NULL;
    CHECK(palp_session_create_udp(scene, &params, &dev, &session) == PALP_OK);
    if (!session) return;
    const int fd = open_sender(palp_session_udp_port(session));
    CHECK(fd >= 0);
    CHECK(palp_session_start(session) == PALP_OK);
    int forces = 0, pressed = 0, right = 0;
    for (int i = 0; i < 500 && fd >= 0; ++i) {
        CHECK(send_state(fd, (uint64_t)i + 1, press_y(i), 0.0));
        sleep_ms(1);
        force_message f;
        while (receive_force(fd, &f, 0)) {
            ++forces;
            if (f.state_sequence < 320 || f.force_scale != 1.0) continue; /* pressed, held */
            ++pressed;
            /* Held 3 mm deep, the proxy on the skin within half a voxel: 0.75-1.05 N. */
            right += f.force[1] < 0.0 && fabs(norm3(f.force) - 0.9) < 0.15;
        }
    }
    CHECK(palp_session_stop(session) == PALP_OK);
    palp_snapshot s;
    CHECK(palp_session_latest(session, &s) == PALP_OK);
    printf("servo thread: %llu ticks, %d forces received, %d while held, %d of them k D\n",
           (unsigned long long)s.tick, forces, pressed, right);
    CHECK(forces > 100);
    CHECK(pressed > 20);
    CHECK(right == pressed);
    if (fd >= 0) close(fd);
    palp_session_release(session);
}

int main(void) {
    palp_volume* volume = NULL;
    CHECK(palp_volume_make_phantom("avc", 0, NULL, 1e-3, &volume) == PALP_OK);
    palp_scene* scene = NULL;
    CHECK(palp_scene_from_volume(volume, -500.0, 500.0, &scene) == PALP_OK);
    palp_volume_release(volume);
    if (!scene) return 1;
    test_bad_inputs(scene);
    test_offline_press(scene);
    test_realtime_press(scene);
    palp_scene_release(scene);
    if (gFailures) fprintf(stderr, "%d failure(s)\n", gFailures);
    return gFailures ? 1 : 0;
}
