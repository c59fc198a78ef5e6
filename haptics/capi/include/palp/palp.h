#ifndef PALP_PALP_H
#define PALP_PALP_H
/**
 * @file
 * palp's C API: load, generate or copy from memory a volume, build a scene (rigid or deformable
 * tissue), run a haptic session on a simulated device or a host's device (callbacks) in real time
 * or offline, read its state (and the deformed surface) and change its parameters while it runs.
 *
 * Conventions
 * - Opaque handles (palp_volume, palp_scene, palp_session) are reference counted: a create
 *   function returns a handle holding one reference; palp_X_retain() adds one,
 *   palp_X_release() drops one and frees the object at zero. Releasing NULL is a no-op. A
 *   scene keeps what it needs of its volume, and a session what it needs of its scene, so
 *   handles may be released in any order.
 * - Every function that can fail returns a palp_status. On failure, palp_last_error() (per
 *   calling thread) holds a message naming the value or file, what was expected and what was
 *   found, and the error callback (if set) is called with the same status and message. Output
 *   arguments are left untouched on failure.
 * - No C++ exception ever crosses this boundary.
 * - Units are SI throughout: metres, seconds, newtons, N/m. The world frame is the DICOM
 *   patient frame (LPS) of the volume, in metres.
 *
 * Threading
 * - Volumes and scenes are immutable after creation and may be shared between threads.
 * - A session has three roles: a controlling thread (create, start, stop, step, release), one
 *   viewer thread (palp_session_latest, palp_session_latest_surface, palp_session_pop_trace),
 *   and one producer thread (palp_session_set_*, palp_session_reset_observer). These may be
 *   the same thread. Loop statistics may be read from any thread; the realtime status
 *   (palp_session_realtime*) is written while palp_session_start runs, so read it from the
 *   controlling thread (or after synchronising with it), never during a start.
 *   palp_session_get_params may be called from any thread.
 */

#include <stddef.h>
#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

#define PALP_VERSION_MAJOR 0
#define PALP_VERSION_MINOR 1
#define PALP_VERSION_PATCH 0

/** Result of every fallible call. */
typedef enum palp_status {
    PALP_OK = 0,
    PALP_ERROR_INVALID_ARGUMENT = 1, /**< a NULL handle or pointer, or a value out of range */
    PALP_ERROR_IO = 2,               /**< a file could not be opened, read or written */
    PALP_ERROR_FORMAT = 3,           /**< a file's content is not what its format requires */
    PALP_ERROR_STATE = 4,            /**< the call does not fit the object's state */
    PALP_ERROR_QUEUE_FULL = 5,       /**< the session's command queue is full: retry later */
    PALP_ERROR_OUT_OF_MEMORY = 6,
    PALP_ERROR_REALTIME = 7, /**< real-time scheduling was required but refused */
    PALP_ERROR_INTERNAL = 8  /**< anything else (a bug: please report the message) */
} palp_status;

typedef struct palp_volume palp_volume;
typedef struct palp_scene palp_scene;
typedef struct palp_session palp_session;

/** "MAJOR.MINOR.PATCH" of the library (static storage). */
const char* palp_version(void);
/** Name of a status code, e.g. "PALP_ERROR_IO" (static storage). */
const char* palp_status_string(palp_status status);
/** Message of the last failed call on this thread ("" when none; valid until the next failing
 *  call on this thread). */
const char* palp_last_error(void);

/** Called on every failure, on the failing thread, after palp_last_error() is set. */
typedef void (*palp_error_callback)(void* user, palp_status status, const char* message);
/** Sets (or with NULL clears) the process-wide error callback. */
void palp_set_error_callback(palp_error_callback callback, void* user);

/* ---- Volumes --------------------------------------------------------------------------- */

/** Loads a scan: a DICOM directory or file, NIfTI, NRRD, MetaImage or a palp .vdb.
 *  @p voxel_size: isotropic voxel edge of the resampled grid, m (0: the format's default,
 *  the finest input spacing). Errors: PALP_ERROR_IO (cannot read), PALP_ERROR_FORMAT,
 *  PALP_ERROR_INVALID_ARGUMENT. */
palp_status palp_volume_load(const char* path, double voxel_size, palp_volume** out);

/** Generates one of the thesis's phantoms as a CT-like volume (HU; surface at y = 0 facing -y,
 *  depth +y; see palp/volume/phantom.h).
 *  @p scene: "avc", "avcec", "bone" or "stiffness".
 *  @p variant: avc: quadrant of the hidden box 0..3; bone: displacement -1..1; else ignored.
 *  @p shape: avcec plate outline "circle", "triangle", "rectangle", "hexagon", "pentagon"
 *  (NULL: circle); ignored otherwise.
 *  @p voxel_size: m (> 0; 0.5e-3 to 1e-3 is typical). */
palp_status palp_volume_make_phantom(const char* scene, int variant, const char* shape,
                                     double voxel_size, palp_volume** out);

/** Scalar type of a host's voxels (native byte order). */
typedef enum palp_value_type {
    PALP_VALUE_I8 = 0,
    PALP_VALUE_U8 = 1,
    PALP_VALUE_I16 = 2,
    PALP_VALUE_U16 = 3,
    PALP_VALUE_I32 = 4,
    PALP_VALUE_U32 = 5,
    PALP_VALUE_F32 = 6,
    PALP_VALUE_F64 = 7
} palp_value_type;

/** Frame and unit of a host's index-to-world affine (palp's world is LPS in metres; RAS, the
 *  frame of NIfTI and 3D Slicer, negates x and y). */
typedef enum palp_world_frame {
    PALP_FRAME_LPS_M = 0,
    PALP_FRAME_RAS_M = 1,
    PALP_FRAME_LPS_MM = 2,
    PALP_FRAME_RAS_MM = 3 /**< e.g. 3D Slicer's IJKToRAS matrix */
} palp_world_frame;

/** A volume from a host's buffer (copied; @p data may be freed after the call): voxel (i, j, k)
 *  (0 <= i < dims[0], ...) is the @p type value at byte offset i strides[0] + j strides[1] +
 *  k strides[2] from @p data (unaligned is fine) and lies at index_to_world (row-major 4x4,
 *  last row 0 0 0 1) times (i, j, k, 1) in @p frame. @p strides: bytes, positive, not
 *  overlapping (NULL or all 0: packed, i fastest; a C-ordered numpy array [k][j][i] has strides
 *  (s[2], s[1], s[0])). @p voxel_size as for palp_volume_load (0: the finest spacing).
 *  Checked like the file readers, with their texts: dims (1..2^31-1, product within 8 GiB of
 *  floats), strides, a finite affine with independent axes (spacing 1 um..0.1 m) and an origin
 *  within 10 m, values finite within the volume range. Errors: PALP_ERROR_INVALID_ARGUMENT
 *  naming the value ("palp_volume_from_memory: strides[1]: expected ..., found ..."). */
palp_status palp_volume_from_memory(const void* data, palp_value_type type, const int64_t dims[3],
                                    const int64_t strides[3], const double index_to_world[16],
                                    palp_world_frame frame, double voxel_size, palp_volume** out);

/** Voxel edge, m, and the world box of the active voxels, m (either pointer may be NULL). */
palp_status palp_volume_geometry(const palp_volume* volume, double* voxel_size,
                                 double bounds_min[3], double bounds_max[3]);

palp_volume* palp_volume_retain(palp_volume* volume);
void palp_volume_release(palp_volume* volume);

/* ---- Scenes ---------------------------------------------------------------------------- */

/** A scene from a volume: the volume for the volume ray sources, the iso-surface at
 *  @p surface_iso (volume units, e.g. -500 HU for skin) as the surface the proxy slides on, and
 *  the iso-surface at @p hard_iso (e.g. 500 HU for bone and plates) as hard meshes for the mesh
 *  ray source. Pass NAN for either to leave it out. */
palp_status palp_scene_from_volume(const palp_volume* volume, double surface_iso, double hard_iso,
                                   palp_scene** out);
/** An empty scene: nothing to touch (the proxy equals the probe), no volume. */
palp_status palp_scene_create_empty(palp_scene** out);

palp_scene* palp_scene_retain(palp_scene* scene);
void palp_scene_release(palp_scene* scene);

/* ---- Deformable scenes (palp/palp_deformable.h) ---------------------------------------- */

#include "palp/palp_deformable.h" /* included here, after the handles it uses */

/* ---- Sessions -------------------------------------------------------------------------- */

typedef enum palp_coupling_mode {
    PALP_MODE_VC = 0,   /**< plain virtual coupling, k = stiffness */
    PALP_MODE_AVC = 1,  /**< anisotropic: k from the ray length along proxy -> probe */
    PALP_MODE_AVCEC = 2 /**< AVC with the energy-conserving force terms */
} palp_coupling_mode;

typedef enum palp_ray_source {
    PALP_SOURCE_MESH = 0,             /**< closest hit against the scene's hard meshes */
    PALP_SOURCE_VOLUME_FIRST_HIT = 1, /**< first crossing of threshold in the volume */
    PALP_SOURCE_VOLUME_ACCUMULATE = 2 /**< where the integral of hardness reaches tau_stop */
} palp_ray_source;

/** Session parameters. Always start from palp_session_params_default(). */
typedef struct palp_session_params {
    palp_coupling_mode mode;
    palp_ray_source source;
    double stiffness;        /**< k_s, N/m: stiffness of the surface itself */
    double reference_length; /**< L_ref, m: m(L) = clamp(L_ref / L, 1, max_multiplier) */
    double max_multiplier;   /**< m_max (>= 1) */
    double max_stiffness;    /**< k_max, N/m: k is always clamped here; above the device's
                                  maximum stiffness both k_max and k_s are lowered to it
                                  (palp_snapshot.stiffness_limited says so) */
    double damping;          /**< b, N s/m, on v_proxy - v_probe */
    double ray_length;       /**< L_max, m */
    int ring_count;          /**< low-pass ring rays (0..47) */
    double ring_half_angle;  /**< alpha, rad */
    double sobel_angle;      /**< delta, rad: spherical Sobel spacing */
    double surface_offset;   /**< h, m: surface Sobel spacing */
    double threshold;        /**< first-hit threshold (volume units, e.g. HU); accumulate: the
                                  value where the hardness steps up */
    double ray_step;         /**< sample spacing along volume rays, m */
    double hardness;         /**< accumulate: hardness above threshold, 1/m */
    double tau_stop;         /**< accumulate: integral where the ray stops */
    double static_friction;  /**< mu_s */
    double dynamic_friction; /**< mu_d (<= mu_s) */
    /** Device class from palp's spec table ("3D Systems Touch", "3D Systems Touch X",
     *  "Phantom Premium 1.5", "Force Dimension omega.3", "Novint Falcon"); its maximum force
     *  clamps every tick. The string is copied at creation. */
    const char* device;
    int passivity_control;    /**< non-zero: the passivity controller adds damping */
    double period;            /**< servo period T, s (1e-3 for 1 kHz) */
    double startup_threshold; /**< N: force below which a start-up tick is quiet */
    uint32_t startup_quiet_ticks;
    double cross_fade_seconds;    /**< run-time coupling changes fade over this long */
    double workspace_scale;       /**< world = offset + scale * rotation * device */
    double workspace_rotation[9]; /**< row-major 3x3 rotation */
    double workspace_offset[3];   /**< m */
    uint32_t trace_capacity;      /**< snapshots kept for palp_session_pop_trace (0: none) */
    int servo_cpu;                /**< core to pin the servo thread to; -1: the last one */
    int servo_priority;           /**< SCHED_FIFO priority 1..99; 0: do not ask */
    int require_realtime;         /**< non-zero: start fails if pinning/SCHED_FIFO is refused */
    /** non-zero (default): while the servo runs, the process's other threads are kept off its
     *  CPU (their affinity masks lose it until stop; reported as "N other threads moved off
     *  it"); 0: they share it */
    int servo_reserve_cpu;
    /** AVC/AVCEC ring rays: width of their Gaussian weight exp(-alpha^2 / (2 sigma^2)) in the
     *  low-pass of k, rad (> 0 and <= pi/2 when ring_count > 0; default 0.1) */
    double ring_weight_sigma;
    /** Deformable tissue: after the tissue springs back past the free probe, the force's
     *  magnitude may rise by at most recontact_rise_nps for this long (and then until the
     *  coupling's force is within that limit), s (0..1; 0: no limit; default 0.015) */
    double recontact_seconds;
    double recontact_rise_nps; /**< N/s (> 0; default 100) */
    /** AVCEC: the rays' largest tilt from the contact normal, rad (0.01..pi/2; default 0.05;
     *  pi/2: no limit, the rays along the proxy-probe direction as in the thesis) */
    double max_ray_tilt;
} palp_session_params;

/** Fills @p params with palp's defaults (AVCEC, volume first-hit 300 HU, k_s 300 N/m, Touch X,
 *  1 kHz, identity workspace). */
void palp_session_params_default(palp_session_params* params);

typedef enum palp_trajectory_kind {
    PALP_TRAJECTORY_PRESS = 0,   /**< in along direction by depth, hold, back out */
    PALP_TRAJECTORY_SWEEP = 1,   /**< back and forth along direction, pressed depth */
    PALP_TRAJECTORY_RASTER = 2,  /**< boustrophedon over extent_u x extent_v, pressed depth */
    PALP_TRAJECTORY_CIRCLE = 3,  /**< circle of radius in (u, v), pressed depth */
    PALP_TRAJECTORY_SINUSOID = 4 /**< centre + a(t) sin(2 pi f t) direction */
} palp_trajectory_kind;

/** A scripted path for the simulated user's hand (device frame, m), and the hand model that
 *  follows it under the rendered force. Start from palp_trajectory_default(). */
typedef struct palp_trajectory {
    palp_trajectory_kind kind;
    double centre[3];          /**< press/sinusoid: start point; others: centre on the surface */
    double direction[3];       /**< press: into the surface; sweep: sweep axis; sinusoid: axis */
    double press_direction[3]; /**< sweep, raster, circle: into the surface */
    double u[3], v[3];         /**< raster, circle: the plane's axes */
    double depth;              /**< press, sweep, raster, circle: m */
    double length;             /**< sweep: length of the line, m */
    double extent_u, extent_v; /**< raster: size of the rectangle, m */
    double line_spacing;       /**< raster: m */
    double speed;              /**< sweep, raster: m/s */
    double radius;             /**< circle: m */
    double frequency;          /**< circle, sinusoid: Hz, >= 0 (a circle turns from u toward v) */
    double amplitude;          /**< sinusoid: m */
    double grow_seconds;       /**< sinusoid: amplitude ramp, s (0: none) */
    double press_seconds;      /**< press: s */
    double hold_seconds;       /**< press: s */
    double approach;           /**< sweep, raster, circle: start this far above the surface, m */
    double approach_seconds;   /**< sweep, raster, circle: s */
    double turn_seconds;       /**< sweep: s */
    double hand_mass;          /**< kg */
    double hand_stiffness;     /**< N/m: the arm's pull towards the path */
    double hand_damping;       /**< N s/m */
} palp_trajectory;

/** Fills @p trajectory with the defaults of @p kind (palp/haptics/devices/trajectory.h). */
palp_status palp_trajectory_default(palp_trajectory_kind kind, palp_trajectory* trajectory);

/** Bits of palp_snapshot.fault_flags: what went wrong in a tick (docs/architecture.md). */
typedef enum palp_fault {
    PALP_FAULT_STALE = 1,             /**< no new sample (a repeated one, or none) */
    PALP_FAULT_NON_FINITE = 2,        /**< NaN or infinite position, velocity or time */
    PALP_FAULT_OUT_OF_RANGE = 4,      /**< outside spec's workspace + 0.1 m, or 10 km away */
    PALP_FAULT_TOO_FAST = 8,          /**< over 10 m/s, or a jump from the last good sample */
    PALP_FAULT_FORCE_NON_FINITE = 16, /**< the computed force was not finite (last good held) */
    PALP_FAULT_FORCE_JUMP = 32,       /**< the force stepped by more than max_force / 2 (limited) */
    PALP_FAULT_OVERLOAD = 64, /**< the servo loop overran its budget: no force till restart */
    PALP_FAULT_SHED = 128     /**< the loop shed work (VC, tissue frozen); force still rendered */
} palp_fault;

/** One tick's state (world frame, SI units). */
typedef struct palp_snapshot {
    uint64_t tick;
    double time;            /**< s since the first tick */
    double probe[3];        /**< device position in the world, m */
    double proxy[3];        /**< m */
    double force[3];        /**< sent to the device (world frame), N */
    double energy_force[3]; /**< AVCEC spherical term, N */
    double proxy_force[3];  /**< AVCEC surface term, N */
    double stiffness;       /**< k, N/m */
    double ray_length;      /**< L, m */
    double distance;        /**< D = |probe - proxy|, m */
    double coupling_energy; /**< 1/2 k D^2, J */
    double observer_energy; /**< passivity observer W, J */
    double added_damping;   /**< passivity controller alpha, N s/m */
    int contact_count;      /**< active constraint planes 0..3 */
    int rays;               /**< rays cast this tick */
    int sticking, gate_open, faulted, clamped, fading;
    palp_coupling_mode mode;
    uint64_t faults; /**< ticks so far whose force was non-finite or sample refused (held) */
    /** 1: the coupling in force asked for more stiffness than the device renders stably and
     *  k_max (and k_s if above it) were lowered to the device's maximum stiffness. */
    int stiffness_limited;
    /* Deformable scenes only (zero, contact_node -1, otherwise): */
    double tissue_force[3];  /**< mean force on the tissue over the tick's FEM step, N */
    int contact_node;        /**< FEM node with the largest share of the contact, -1: none */
    double max_displacement; /**< largest surface displacement after the step, m */
    uint32_t fem_flags;      /**< solver flags of the step (0: a clean step) */
    /* Host and remote devices' watchdog (palp_session_create_host, palp_session_create_udp;
     * 0 / 0 for simulated devices): */
    int device_stale;          /**< 1: this tick brought no fresh, good sample */
    double device_force_scale; /**< factor the force was scaled by (1: whole, 0: cut) */
    uint64_t watchdog_trips;   /**< outages so far whose force reached zero */
    double passivity_cut;      /**< passivity controller: force cut along the velocity, N */
    uint32_t fault_flags;      /**< this tick's PALP_FAULT_* bits (any device), on the very tick */
    /** Ticks so far with PALP_FAULT_STALE, _NON_FINITE, _OUT_OF_RANGE, _TOO_FAST,
     *  _FORCE_NON_FINITE, _FORCE_JUMP, _OVERLOAD; the session's own ramp's trips to zero force. */
    uint64_t stale_ticks, non_finite_samples, out_of_range_samples, too_fast_samples;
    uint64_t non_finite_forces, force_jumps, overload_ticks, fault_trips;
} palp_snapshot;

typedef struct palp_latency {
    double p50, p99, p999, max, mean; /**< s */
    uint64_t count;
} palp_latency;

typedef struct palp_loop_stats {
    palp_latency wake_latency; /**< actual wake-up minus deadline */
    palp_latency period_error; /**< |actual period - T| */
    palp_latency compute;      /**< time in one tick */
    uint64_t ticks, misses, skipped;
    uint64_t trace_dropped;       /**< snapshots lost because the trace was not read in time */
    int overloaded, fifo_dropped; /**< 2 x 0.4 s with > half the deadlines missed; FIFO dropped */
    double overloaded_at;         /**< when, s: no force from then until restarted */
    /** 1: one 0.4 s window over budget: work shed (VC for AVC/AVCEC, tissue frozen), force still
     *  rendered, restored after 10 s of calm; counts this run; shed_at: the last shed, s */
    int shedding;
    uint64_t sheds, restores;
    double shed_at;
} palp_loop_stats;

typedef struct palp_realtime {
    int pinned, cpu, fifo, priority, memory_locked, failed;
    const char* message; /**< every outcome, e.g. "pinned to CPU 1; SCHED_FIFO 80 refused: ...";
                              valid until the session is restarted or released */
} palp_realtime;

/** A session on a simulated device whose hand follows @p trajectory.
 *  Errors: PALP_ERROR_INVALID_ARGUMENT naming the field (unknown device class, a ray source
 *  without its data in the scene, values out of range). */
palp_status palp_session_create_simulated(palp_scene* scene, const palp_session_params* params,
                                          const palp_trajectory* trajectory, palp_session** out);

/* ---- Host devices ---------------------------------------------------------------------- */

/** One sample of a host's device, in the device frame (world = workspace transform of it). */
typedef struct palp_device_state {
    double position[3]; /**< end-effector position, m */
    double velocity[3]; /**< end-effector velocity, m/s */
    uint32_t buttons;   /**< bit i set: button i pressed */
    /** The host's sample counter: a sample is new when its sequence or its timestamp differs
     *  from the last new sample's. Repeat the last values when nothing new has arrived (or
     *  return non-zero from read_state): the watchdog then counts the tick as missing. */
    uint64_t sequence;
    double timestamp; /**< when the sample was taken (host clock), s */
} palp_device_state;

/** A device's limits. Start from palp_device_spec_from_class(). */
typedef struct palp_device_spec {
    double max_force;            /**< N (0 < f <= 1000): every tick's force is clamped here */
    double max_continuous_force; /**< N (0..1000; informative) */
    double max_stiffness;        /**< highest stable stiffness, N/m (0..1e6; 0: no limit):
                                      palp_session_params.max_stiffness is lowered to it */
    double max_damping;          /**< highest stable damping, N s/m (0..1e4; 0: no limit); with
                                      the period it bounds the stiffness too (k < 1.8 b / T)
                                      and caps the passivity controller's damping */
    double workspace_min[3];     /**< device frame, m: samples outside it + 0.1 m are refused
                                      (no volume, e.g. all 0: outside +-10 m) */
    double workspace_max[3];     /**< device frame, m (>= workspace_min) */
} palp_device_spec;

/** The spec of a device class of palp's table (the names of palp_session_params.device).
 *  PALP_ERROR_INVALID_ARGUMENT naming the class when there is none. */
palp_status palp_device_spec_from_class(const char* device_class, palp_device_spec* out);

/** Fills @p state with the newest sample and returns 0; returns non-zero when there is no
 *  sample this tick (@p state is then ignored). @p state holds the last sample on entry. */
typedef int (*palp_device_read_fn)(void* user, palp_device_state* state);
/** Sends @p force (device frame, N; already clamped to spec.max_force) to the device. */
typedef void (*palp_device_write_fn)(void* user, const double force[3]);

/** A device made of host callbacks. Start from palp_device_callbacks_default().
 *
 *  The callbacks run on the servo thread (palp_session_start) or on the thread that calls
 *  palp_session_step, once per tick each (read_state, then write_force), and never at the
 *  same time. They must
 *  - return in bounded time, well inside the period (a few microseconds: they are part of the
 *    1 ms tick), and never wait: no I/O that may block, no sleeping;
 *  - take no lock that another thread may hold (exchange data with lock-free buffers or
 *    atomics: a lock held by a descheduled thread stalls the loop);
 *  - allocate no memory (malloc, new) and not call into palp;
 *  - not unwind (no C++ exception, no longjmp) through palp.
 *  @p user is passed back unchanged; it must stay valid while the session exists.
 *
 *  The watchdog: after watchdog_grace seconds without a new sample (ticks x period) the force
 *  ramps linearly to zero, reached at watchdog_timeout (a trip: palp_snapshot.watchdog_trips);
 *  once new samples arrive it climbs back to whole over watchdog_resume seconds, so a hand
 *  that moved during the outage is not kicked. While samples are missing the probe holds the
 *  last sample's position with zero velocity. A bad sample (palp_fault) counts as missing too and
 *  is refused (the last good force is held, palp_snapshot.faulted) until the ramp cuts it. */
typedef struct palp_device_callbacks {
    palp_device_read_fn read_state;   /**< required */
    palp_device_write_fn write_force; /**< NULL: forces are not sent (a tracker) */
    void* user;                       /**< passed to both callbacks */
    palp_device_spec spec;            /**< default: "3D Systems Touch X"'s */
    /** Reported as palp_session_params.device by palp_session_get_params (copied at creation;
     *  NULL: "host device"); palp_session_set_params expects it there. */
    const char* name;
    double watchdog_timeout; /**< s: zero force after this long without a new sample
                                  (0 < t <= 10; default 0.01) */
    double watchdog_grace;   /**< s: the force stays whole this long (0 <= g < timeout;
                                  default 0.002) */
    double watchdog_resume;  /**< s: time for the force to climb back (0..10; default 0.05) */
} palp_device_callbacks;

/** Fills @p callbacks with NULL callbacks, NULL user and name, "3D Systems Touch X"'s spec
 *  and the watchdog defaults. */
void palp_device_callbacks_default(palp_device_callbacks* callbacks);

/** A session on a host's device (@p device's callbacks, copied). @p params as for
 *  palp_session_create_simulated, except that params->device is ignored (the spec is
 *  device->spec). Errors: PALP_ERROR_INVALID_ARGUMENT naming the field
 *  ("palp_device_callbacks.spec.max_force", ...). */
palp_status palp_session_create_host(palp_scene* scene, const palp_session_params* params,
                                     const palp_device_callbacks* device, palp_session** out);

/* ---- Remote devices: the device bridge over UDP (docs/device_bridge.md) ---------------- */

/** How a remote device's session listens and when its force is cut. Start from
 *  palp_udp_device_params_default(). The remote program sends bridge State datagrams to
 *  @p listen and receives one Force datagram per tick back at the address its newest State came
 *  from (palp_session_udp_port() says which port was bound). */
typedef struct palp_udp_device_params {
    /** Local address to bind, "host:port" or "[ipv6]:port" (port 0: any free one); copied at
     *  creation. Default "127.0.0.1:7405". */
    const char* listen;
    palp_device_spec spec; /**< the remote device's limits; default "3D Systems Touch X"'s */
    /** Reported as palp_session_params.device by palp_session_get_params (copied; NULL: "udp
     *  device"); palp_session_set_params expects it there. */
    const char* name;
    double watchdog_timeout;  /**< s: zero force after this long without a new State
                                   (0 < t <= 10; default 0.01) */
    double watchdog_grace;    /**< s: the force stays whole this long (0 <= g < timeout;
                                   default 0.002) */
    double watchdog_resume;   /**< s: time for the force to climb back (0..10; default 0.05) */
    int max_drain;            /**< most datagrams one tick takes from the socket (1..4096;
                                   default 64) */
    int receive_buffer_bytes; /**< SO_RCVBUF asked for, bytes (0: the system's; default 256 KiB) */
} palp_udp_device_params;

/** Fills @p params with the defaults above. */
void palp_udp_device_params_default(palp_udp_device_params* params);

/** A session for a remote device (what `palp serve` runs): the socket is opened and bound here,
 *  each tick drains it without waiting and sends the force back without blocking, and a
 *  WatchdogDevice cuts the force when States stop coming (as for host devices: grace, ramp to
 *  zero at the timeout, a trip per outage, climb back over resume). Before the first State the
 *  device rests at the origin, stale, with no force and nothing sent. Malformed or foreign
 *  datagrams are ignored and counted (palp_session_udp_counters). @p params as for
 *  palp_session_create_simulated, except that params->device is ignored (the spec is
 *  device->spec). Runs on the servo thread (palp_session_start) or offline
 *  (palp_session_step: each step reads what has arrived by then).
 *  Errors: PALP_ERROR_INVALID_ARGUMENT naming the field ("palp_udp_device_params.listen
 *  'localhost7405': expected host:port ...", "palp_udp_device_params.spec.max_force", ...);
 *  PALP_ERROR_IO when the socket cannot be bound (the address and the system's reason, e.g.
 *  "Address already in use (EADDRINUSE)"). */
palp_status palp_session_create_udp(palp_scene* scene, const palp_session_params* params,
                                    const palp_udp_device_params* device, palp_session** out);

/** The bound UDP port of a remote device's session (the system's choice for port 0); 0 for
 *  any other session or NULL. Any thread. */
int palp_session_udp_port(const palp_session* session);
/** The bound address, "host:port" (valid while the session lives); NULL for any other session
 *  or NULL. Any thread. */
const char* palp_session_udp_address(const palp_session* session);

/** What a remote device's session has received and sent so far (each count read on its own,
 *  from any thread). */
typedef struct palp_udp_device_counters {
    uint64_t received;     /**< States accepted */
    uint64_t superseded;   /**< accepted, but a newer one arrived for the same tick */
    uint64_t lost;         /**< sequence numbers skipped between accepted States */
    uint64_t late;         /**< not newer than the last accepted (ignored) */
    uint64_t restarts;     /**< the sender's sequence fell back by more than 1024 */
    uint64_t peer_changes; /**< a State came from another address than the last one */
    uint64_t ignored;      /**< malformed or foreign datagrams: the five counts below */
    uint64_t short_datagrams, bad_magic, bad_version, bad_type, bad_size;
    uint64_t receive_errors; /**< recvfrom failed other than "nothing queued" */
    uint64_t drain_limited;  /**< ticks that stopped at max_drain datagrams */
    uint64_t forces_sent, forces_send_failed;
} palp_udp_device_counters;

/** A remote device's newest State as palp accepted it (device frame). */
typedef struct palp_udp_state {
    uint64_t sequence;     /**< the sender's sequence (0 before any State) */
    uint64_t time_ns;      /**< the sender's time_ns */
    double position[3];    /**< m */
    double orientation[4]; /**< unit quaternion w, x, y, z (identity when the device has none) */
    double velocity[3];    /**< m/s */
    uint32_t buttons;      /**< bit i set: button i pressed */
} palp_udp_state;

/** Viewer: the newest State the servo thread accepted, published lock-free each tick, for
 *  what a palp_snapshot lacks (the orientation and the buttons); may skip States. Call it from
 *  one viewer thread only (the one that calls palp_session_latest). PALP_ERROR_STATE for a
 *  session that is not a remote device's. */
palp_status palp_session_udp_state(palp_session* session, palp_udp_state* out);

/** The counters of a remote device's session; PALP_ERROR_STATE for any other session. */
palp_status palp_session_udp_counters(const palp_session* session, palp_udp_device_counters* out);

palp_session* palp_session_retain(palp_session* session);
/** Drops a reference; the last one stops the servo thread and frees the session. */
void palp_session_release(palp_session* session);

/** Runs the session on its own real-time servo thread (PALP_ERROR_STATE if running). */
palp_status palp_session_start(palp_session* session);
/** Stops the servo thread (idempotent). */
palp_status palp_session_stop(palp_session* session);
/** 1 while the servo thread runs, 0 otherwise (also for NULL). */
int palp_session_running(const palp_session* session);
/** Runs @p ticks ticks on the calling thread as fast as possible (offline; time advances by
 *  the period per tick) and copies the last one's state into @p last (may be NULL). With
 *  @p ticks 0 nothing runs and @p last gets the newest tick as it is (the servo thread's last
 *  after a run; before any tick what palp_session_latest gives: zeros, device_force_scale 1).
 *  PALP_ERROR_STATE while the servo thread runs. */
palp_status palp_session_step(palp_session* session, uint32_t ticks, palp_snapshot* last);

/** Viewer: the newest published tick. */
palp_status palp_session_latest(palp_session* session, palp_snapshot* out);
/** Viewer: the newest published tick's deformed surface: vertex_count x 3 positions (world,
 *  m; in the order of palp_scene_surface_topology's vertices) into @p vertices, whose
 *  @p vertex_capacity (in vertices) must hold them all; @p tick (may be NULL) receives the
 *  palp_snapshot.tick it belongs to (the rest surface with tick 0 before the first tick).
 *  Never blocks the servo thread (frames preallocated, a lock-free triple buffer). Call it from
 *  the viewer thread. PALP_ERROR_STATE on a rigid scene's session. */
palp_status palp_session_latest_surface(palp_session* session, float* vertices,
                                        size_t vertex_capacity, uint64_t* tick);
/** Viewer: the oldest unread tick of the trace; *got = 0 when none is queued. */
palp_status palp_session_pop_trace(palp_session* session, palp_snapshot* out, int* got);

/** Producer: switch the coupling mode (cross-faded). PALP_ERROR_QUEUE_FULL: retry later. */
palp_status palp_session_set_mode(palp_session* session, palp_coupling_mode mode);
/** Producer: apply the coupling, friction and passivity fields of @p params (the coupling
 *  cross-faded). All or nothing: everything is validated first, and the three changes travel
 *  as one command that takes effect at one tick, so on PALP_ERROR_QUEUE_FULL (retry later) or
 *  any other error nothing was applied and palp_session_get_params is unchanged.
 *  The fields fixed at creation (device, period, start-up gate, cross-fade time, workspace,
 *  trace capacity, servo) must equal the session's: PALP_ERROR_INVALID_ARGUMENT otherwise.
 *  Stiffness above the device's maximum is lowered to it (see max_stiffness). */
palp_status palp_session_set_params(palp_session* session, const palp_session_params* params);
/** The parameters in force after the last successful set call (or creation), with stiffness
 *  and max_stiffness as rendered (lowered to the device's maximum when they were above). */
palp_status palp_session_get_params(const palp_session* session, palp_session_params* out);
/** Producer: set the passivity observer's energy back to zero. */
palp_status palp_session_reset_observer(palp_session* session);

/** Servo loop timing since start (zeros before the first start). */
palp_status palp_session_stats(const palp_session* session, palp_loop_stats* out);
/** What the operating system granted the servo thread (after start). */
palp_status palp_session_realtime(const palp_session* session, palp_realtime* out);
/** palp_realtime.message alone ("" before the first start; NULL for a NULL session). */
const char* palp_session_realtime_status(const palp_session* session);

#ifdef __cplusplus
}
#endif

#endif /* PALP_PALP_H */
