// The C API (palp/palp.h): a thin layer over palp::haptics that converts plain C structs,
// counts references and turns every exception into a status code plus a message.

#include <array>
#include <atomic>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <exception>
#include <memory>
#include <mutex>
#include <new>
#include <string>
#include <type_traits>
#include <utility>

#include "palp/base/error.h"
#include "palp/haptics/session.h"
#include "palp/haptics/simulated_device.h"
#include "palp/haptics/trajectory.h"
#include "palp/palp.h"
#include "palp/volume/load.h"
#include "palp/volume/phantom.h"

namespace ph = palp::haptics;
namespace pv = palp::volume;

struct palp_volume {
    std::atomic<int> refs{1};
    pv::Volume volume;
};

struct palp_scene {
    std::atomic<int> refs{1};
    std::shared_ptr<const ph::Scene> scene;
};

struct palp_session {
    std::atomic<int> refs{1};
    std::string deviceName;          // params.device points here
    palp_session_params params;      // in force; guarded by paramsMutex (producer and controller)
    mutable std::mutex paramsMutex;  // never taken by the servo thread
    std::unique_ptr<ph::SimulatedDevice> device;
    std::unique_ptr<ph::Session> session;  // declared last: destroyed (and stopped) first
    ~palp_session() { session.reset(); }
};

namespace {

thread_local std::string tLastError;

std::mutex gCallbackMutex;  // guards the two below (set rarely, read on failures only)
palp_error_callback gCallback = nullptr;
void* gCallbackUser = nullptr;

palp_status fail(palp_status status, const char* message) noexcept {
    try {
        tLastError = message;
    } catch (...) {
        tLastError.clear();  // no memory for the message: an empty one is still valid
    }
    palp_error_callback cb = nullptr;
    void* user = nullptr;
    {
        std::lock_guard<std::mutex> lock(gCallbackMutex);
        cb = gCallback;
        user = gCallbackUser;
    }
    if (cb) cb(user, status, tLastError.c_str());
    return status;
}

// Runs @p body, mapping every exception to a status (the only place exceptions stop).
template <typename Body>
palp_status guarded(Body&& body) noexcept {
    try {
        return body();
    } catch (const palp::ValueError& e) {
        return fail(PALP_ERROR_INVALID_ARGUMENT, e.what());
    } catch (const palp::IoError& e) {
        return fail(PALP_ERROR_IO, e.what());
    } catch (const palp::FormatError& e) {
        return fail(PALP_ERROR_FORMAT, e.what());
    } catch (const std::bad_alloc&) {
        return fail(PALP_ERROR_OUT_OF_MEMORY, "palp: out of memory");
    } catch (const std::exception& e) {
        return fail(PALP_ERROR_INTERNAL, e.what());
    } catch (...) {
        return fail(PALP_ERROR_INTERNAL, "palp: unknown exception");
    }
}

palp_status nullArgument(const char* function, const char* argument) noexcept {
    std::string m;
    try {
        m = std::string(function) + ": expected a non-NULL " + argument + ", found NULL";
    } catch (...) {
    }
    return fail(PALP_ERROR_INVALID_ARGUMENT, m.c_str());
}

template <typename Handle>
Handle* retain(Handle* h) noexcept {
    if (h) h->refs.fetch_add(1, std::memory_order_relaxed);
    return h;
}

template <typename Handle>
void release(Handle* h) noexcept {
    // acq_rel: the last owner sees every other owner's writes before deleting.
    if (h && h->refs.fetch_sub(1, std::memory_order_acq_rel) == 1) delete h;
}

Eigen::Vector3d vec(const double v[3]) { return Eigen::Vector3d(v[0], v[1], v[2]); }
void put(const Eigen::Vector3d& v, double out[3]) noexcept {
    out[0] = v.x();
    out[1] = v.y();
    out[2] = v.z();
}

std::string str(double v) { return std::to_string(v); }

// --- session parameters ----------------------------------------------------------------

ph::CouplingMode toMode(palp_coupling_mode m) {
    switch (m) {
        case PALP_MODE_VC:
            return ph::CouplingMode::VC;
        case PALP_MODE_AVC:
            return ph::CouplingMode::AVC;
        case PALP_MODE_AVCEC:
            return ph::CouplingMode::AVCEC;
    }
    throw palp::ValueError(
        "palp_session_params.mode: expected PALP_MODE_VC, _AVC or _AVCEC, found " +
        std::to_string(static_cast<int>(m)));
}

palp_coupling_mode fromMode(ph::CouplingMode m) noexcept {
    switch (m) {
        case ph::CouplingMode::VC:
            return PALP_MODE_VC;
        case ph::CouplingMode::AVC:
            return PALP_MODE_AVC;
        case ph::CouplingMode::AVCEC:
            return PALP_MODE_AVCEC;
    }
    return PALP_MODE_VC;
}

ph::RaySource toSource(palp_ray_source s) {
    switch (s) {
        case PALP_SOURCE_MESH:
            return ph::RaySource::Mesh;
        case PALP_SOURCE_VOLUME_FIRST_HIT:
            return ph::RaySource::VolumeFirstHit;
        case PALP_SOURCE_VOLUME_ACCUMULATE:
            return ph::RaySource::VolumeAccumulate;
    }
    throw palp::ValueError(
        "palp_session_params.source: expected PALP_SOURCE_MESH, _VOLUME_FIRST_HIT or "
        "_VOLUME_ACCUMULATE, found " +
        std::to_string(static_cast<int>(s)));
}

palp_ray_source fromSource(ph::RaySource s) noexcept {
    switch (s) {
        case ph::RaySource::Mesh:
            return PALP_SOURCE_MESH;
        case ph::RaySource::VolumeFirstHit:
            return PALP_SOURCE_VOLUME_FIRST_HIT;
        case ph::RaySource::VolumeAccumulate:
            return PALP_SOURCE_VOLUME_ACCUMULATE;
    }
    return PALP_SOURCE_MESH;
}

const ph::DeviceSpec& deviceSpec(const char* name) {
    if (!name)
        throw palp::ValueError("palp_session_params.device: expected a device class, found NULL");
    if (const ph::DeviceSpec* s = ph::findDeviceSpec(name)) return *s;
    std::string choices;
    for (const ph::DeviceSpec& s : ph::deviceSpecs()) {
        choices += (choices.empty() ? "'" : ", '") + std::string(s.name) + "'";
    }
    throw palp::ValueError("palp_session_params.device: expected one of " + choices + ", found '" +
                           name + "'");
}

ph::CouplingParams toCoupling(const palp_session_params& p) {
    ph::CouplingParams c;
    c.mode = toMode(p.mode);
    c.source = toSource(p.source);
    c.baseStiffness = p.stiffness;
    c.referenceLength = p.reference_length;
    c.maxMultiplier = p.max_multiplier;
    c.maxStiffness = p.max_stiffness;
    c.damping = p.damping;
    c.bundle.length = p.ray_length;
    c.bundle.ringCount = p.ring_count;
    c.bundle.ringHalfAngle = p.ring_half_angle;
    c.bundle.sobelAngle = p.sobel_angle;
    c.bundle.surfaceOffset = p.surface_offset;
    c.firstHit.threshold = static_cast<float>(p.threshold);
    c.firstHit.step = p.ray_step;
    c.accumulate.step = p.ray_step;
    c.accumulate.tauStop = p.tau_stop;
    if (!std::isfinite(p.hardness) || p.hardness < 0 || !std::isfinite(p.threshold)) {
        throw palp::ValueError(
            "palp_session_params: expected a finite threshold and a finite hardness >= 0, found "
            "threshold " +
            str(p.threshold) + ", hardness " + str(p.hardness));
    }
    c.accumulate.sigma = palp::kernels::TransferFunction::step(static_cast<float>(p.threshold),
                                                               static_cast<float>(p.hardness));
    c.accumulate.firstHitThreshold = static_cast<float>(p.threshold);
    return c;
}

ph::ProxyParams toProxy(const palp_session_params& p) {
    ph::ProxyParams q;
    q.staticFriction = p.static_friction;
    q.dynamicFriction = p.dynamic_friction;
    return q;
}

ph::SessionParams toSession(const palp_session_params& p) {
    ph::SessionParams s;
    s.proxy = toProxy(p);
    s.coupling = toCoupling(p);
    s.passivityControl = p.passivity_control != 0;
    s.startupThresholdN = p.startup_threshold;
    s.startupQuietTicks = p.startup_quiet_ticks;
    s.crossFadeSeconds = p.cross_fade_seconds;
    s.workspace.scale = p.workspace_scale;
    for (int r = 0; r < 3; ++r) {
        for (int c = 0; c < 3; ++c) s.workspace.rotation(r, c) = p.workspace_rotation[3 * r + c];
    }
    s.workspace.offset = vec(p.workspace_offset);
    s.traceCapacity = p.trace_capacity;
    s.servo.periodSeconds = p.period;
    s.servo.cpu = p.servo_cpu;
    s.servo.priority = p.servo_priority;
    s.servo.requireRealtime = p.require_realtime != 0;
    ph::validateSessionParams(s);
    return s;
}

// The fields a running session cannot change; the first that differs, or nullptr.
const char* fixedFieldChanged(const palp_session_params& a, const palp_session_params& b) {
    if (!b.device || std::strcmp(a.device, b.device) != 0) return "device";
    if (a.period != b.period) return "period";
    if (a.startup_threshold != b.startup_threshold) return "startup_threshold";
    if (a.startup_quiet_ticks != b.startup_quiet_ticks) return "startup_quiet_ticks";
    if (a.cross_fade_seconds != b.cross_fade_seconds) return "cross_fade_seconds";
    if (a.workspace_scale != b.workspace_scale) return "workspace_scale";
    for (int i = 0; i < 9; ++i) {
        if (a.workspace_rotation[i] != b.workspace_rotation[i]) return "workspace_rotation";
    }
    for (int i = 0; i < 3; ++i) {
        if (a.workspace_offset[i] != b.workspace_offset[i]) return "workspace_offset";
    }
    if (a.trace_capacity != b.trace_capacity) return "trace_capacity";
    if (a.servo_cpu != b.servo_cpu) return "servo_cpu";
    if (a.servo_priority != b.servo_priority) return "servo_priority";
    if (a.require_realtime != b.require_realtime) return "require_realtime";
    return nullptr;
}

// --- trajectories ------------------------------------------------------------------------
//
// Each kind's C <-> C++ correspondence is written once, as a table of (C field, C++ member,
// check); palp_trajectory_default (fill) and toTrajectory (convert) both walk it. Vectors come
// first, then scalars, each in table order: the first invalid field is the one reported.

enum class Check : std::uint8_t {
    Finite,       // vector: finite coordinates
    Unit,         // vector: finite and non-zero, normalised
    NonNegative,  // scalar: finite, >= 0
    Positive      // scalar: finite, > 0
};

template <typename T>
struct VectorField {
    double (palp_trajectory::*c)[3];
    Eigen::Vector3d T::*t;
    const char* name;
    Check check;
};

template <typename T>
struct ScalarField {
    double palp_trajectory::*c;
    double T::*t;
    const char* name;
    Check check;
};

template <typename T>
struct Layout;

template <>
struct Layout<ph::PressTrajectory> {
    using T = ph::PressTrajectory;
    static constexpr std::array vectors = {
        VectorField<T>{&palp_trajectory::centre, &T::start, "centre", Check::Finite},
        VectorField<T>{&palp_trajectory::direction, &T::direction, "direction", Check::Unit}};
    static constexpr std::array scalars = {
        ScalarField<T>{&palp_trajectory::depth, &T::depthM, "depth", Check::NonNegative},
        ScalarField<T>{&palp_trajectory::press_seconds, &T::pressSeconds, "press_seconds",
                       Check::Positive},
        ScalarField<T>{&palp_trajectory::hold_seconds, &T::holdSeconds, "hold_seconds",
                       Check::NonNegative}};
};

template <>
struct Layout<ph::SweepTrajectory> {
    using T = ph::SweepTrajectory;
    static constexpr std::array vectors = {
        VectorField<T>{&palp_trajectory::centre, &T::centre, "centre", Check::Finite},
        VectorField<T>{&palp_trajectory::direction, &T::direction, "direction", Check::Unit},
        VectorField<T>{&palp_trajectory::press_direction, &T::pressDirection, "press_direction",
                       Check::Unit}};
    static constexpr std::array scalars = {
        ScalarField<T>{&palp_trajectory::length, &T::lengthM, "length", Check::Positive},
        ScalarField<T>{&palp_trajectory::speed, &T::speedMps, "speed", Check::Positive},
        ScalarField<T>{&palp_trajectory::depth, &T::depthM, "depth", Check::NonNegative},
        ScalarField<T>{&palp_trajectory::approach, &T::approachM, "approach", Check::NonNegative},
        ScalarField<T>{&palp_trajectory::approach_seconds, &T::approachSeconds, "approach_seconds",
                       Check::Positive},
        ScalarField<T>{&palp_trajectory::turn_seconds, &T::turnSeconds, "turn_seconds",
                       Check::Positive}};
};

template <>
struct Layout<ph::RasterTrajectory> {
    using T = ph::RasterTrajectory;
    static constexpr std::array vectors = {
        VectorField<T>{&palp_trajectory::centre, &T::centre, "centre", Check::Finite},
        VectorField<T>{&palp_trajectory::u, &T::u, "u", Check::Unit},
        VectorField<T>{&palp_trajectory::v, &T::v, "v", Check::Unit},
        VectorField<T>{&palp_trajectory::press_direction, &T::pressDirection, "press_direction",
                       Check::Unit}};
    static constexpr std::array scalars = {
        ScalarField<T>{&palp_trajectory::extent_u, &T::extentU, "extent_u", Check::Positive},
        ScalarField<T>{&palp_trajectory::extent_v, &T::extentV, "extent_v", Check::NonNegative},
        ScalarField<T>{&palp_trajectory::line_spacing, &T::lineSpacingM, "line_spacing",
                       Check::Positive},
        ScalarField<T>{&palp_trajectory::speed, &T::speedMps, "speed", Check::Positive},
        ScalarField<T>{&palp_trajectory::depth, &T::depthM, "depth", Check::NonNegative},
        ScalarField<T>{&palp_trajectory::approach, &T::approachM, "approach", Check::NonNegative},
        ScalarField<T>{&palp_trajectory::approach_seconds, &T::approachSeconds, "approach_seconds",
                       Check::Positive}};
};

template <>
struct Layout<ph::CircleTrajectory> {
    using T = ph::CircleTrajectory;
    static constexpr std::array vectors = {
        VectorField<T>{&palp_trajectory::centre, &T::centre, "centre", Check::Finite},
        VectorField<T>{&palp_trajectory::u, &T::u, "u", Check::Unit},
        VectorField<T>{&palp_trajectory::v, &T::v, "v", Check::Unit},
        VectorField<T>{&palp_trajectory::press_direction, &T::pressDirection, "press_direction",
                       Check::Unit}};
    static constexpr std::array scalars = {
        ScalarField<T>{&palp_trajectory::radius, &T::radiusM, "radius", Check::NonNegative},
        ScalarField<T>{&palp_trajectory::frequency, &T::frequencyHz, "frequency",
                       Check::NonNegative},
        ScalarField<T>{&palp_trajectory::depth, &T::depthM, "depth", Check::NonNegative},
        ScalarField<T>{&palp_trajectory::approach, &T::approachM, "approach", Check::NonNegative},
        ScalarField<T>{&palp_trajectory::approach_seconds, &T::approachSeconds, "approach_seconds",
                       Check::Positive}};
};

template <>
struct Layout<ph::SinusoidTrajectory> {
    using T = ph::SinusoidTrajectory;
    static constexpr std::array vectors = {
        VectorField<T>{&palp_trajectory::centre, &T::start, "centre", Check::Finite},
        VectorField<T>{&palp_trajectory::direction, &T::direction, "direction", Check::Unit}};
    static constexpr std::array scalars = {
        ScalarField<T>{&palp_trajectory::amplitude, &T::amplitudeM, "amplitude",
                       Check::NonNegative},
        ScalarField<T>{&palp_trajectory::frequency, &T::frequencyHz, "frequency",
                       Check::NonNegative},
        ScalarField<T>{&palp_trajectory::grow_seconds, &T::growSeconds, "grow_seconds",
                       Check::NonNegative}};
};

// Calls @p f with a default-constructed trajectory of @p kind; false for an unknown kind.
template <typename F>
bool forKind(palp_trajectory_kind kind, F&& f) {
    switch (kind) {
        case PALP_TRAJECTORY_PRESS:
            f(ph::PressTrajectory{});
            return true;
        case PALP_TRAJECTORY_SWEEP:
            f(ph::SweepTrajectory{});
            return true;
        case PALP_TRAJECTORY_RASTER:
            f(ph::RasterTrajectory{});
            return true;
        case PALP_TRAJECTORY_CIRCLE:
            f(ph::CircleTrajectory{});
            return true;
        case PALP_TRAJECTORY_SINUSOID:
            f(ph::SinusoidTrajectory{});
            return true;
    }
    return false;
}

// C++ -> C: writes the fields of @p t's kind into @p c (the others untouched).
template <typename T>
void fill(const T& t, palp_trajectory& c) noexcept {
    for (const VectorField<T>& f : Layout<T>::vectors) put(t.*f.t, c.*f.c);
    for (const ScalarField<T>& f : Layout<T>::scalars) c.*f.c = t.*f.t;
}

Eigen::Vector3d unit(const double v[3], const char* field) {
    const Eigen::Vector3d d = vec(v);
    const double n = d.norm();
    if (!(n > 0) || !std::isfinite(n)) {
        throw palp::ValueError(std::string("palp_trajectory.") + field +
                               ": expected a finite non-zero vector, found (" + str(v[0]) + ", " +
                               str(v[1]) + ", " + str(v[2]) + ")");
    }
    return d / n;
}

Eigen::Vector3d finite(const double v[3], const char* field) {
    if (!vec(v).allFinite()) {
        throw palp::ValueError(std::string("palp_trajectory.") + field +
                               ": expected finite coordinates, found NaN/Inf");
    }
    return vec(v);
}

void requireNonNegative(const char* field, double v) {
    if (!(v >= 0) || !std::isfinite(v)) {
        throw palp::ValueError(std::string("palp_trajectory.") + field +
                               ": expected a finite value >= 0, found " + str(v));
    }
}

void requirePositive(const char* field, double v) {
    if (!(v > 0) || !std::isfinite(v)) {
        throw palp::ValueError(std::string("palp_trajectory.") + field +
                               ": expected a finite value > 0, found " + str(v));
    }
}

// C -> C++ for the kind of T, checking every field. @throw palp::ValueError naming the field.
template <typename T>
T convert(const palp_trajectory& c) {
    T t;
    for (const VectorField<T>& f : Layout<T>::vectors) {
        t.*f.t = f.check == Check::Unit ? unit(c.*f.c, f.name) : finite(c.*f.c, f.name);
    }
    for (const ScalarField<T>& f : Layout<T>::scalars) {
        if (f.check == Check::Positive) {
            requirePositive(f.name, c.*f.c);
        } else {
            requireNonNegative(f.name, c.*f.c);
        }
        t.*f.t = c.*f.c;
    }
    return t;
}

ph::Trajectory toTrajectory(const palp_trajectory& c) {
    finite(c.centre, "centre");  // every kind has one; reported before an unknown kind
    ph::Trajectory out;
    if (!forKind(c.kind,
                 [&](const auto& kind) { out = convert<std::decay_t<decltype(kind)>>(c); })) {
        throw palp::ValueError(
            "palp_trajectory.kind: expected PALP_TRAJECTORY_PRESS .. _SINUSOID, found " +
            std::to_string(static_cast<int>(c.kind)));
    }
    return out;
}

ph::HandModel toHand(const palp_trajectory& c) {
    requirePositive("hand_mass", c.hand_mass);
    requireNonNegative("hand_stiffness", c.hand_stiffness);
    requireNonNegative("hand_damping", c.hand_damping);
    ph::HandModel h;
    h.massKg = c.hand_mass;
    h.stiffnessNpm = c.hand_stiffness;
    h.dampingNspm = c.hand_damping;
    return h;
}

std::unique_ptr<ph::SimulatedDevice> makeDevice(const ph::DeviceSpec& spec,
                                                const ph::Trajectory& trajectory,
                                                const ph::HandModel& hand, double period) {
    return std::make_unique<ph::SimulatedDevice>(spec, trajectory, hand, period);
}

// --- snapshots and statistics ------------------------------------------------------------

void toC(const ph::Snapshot& s, palp_snapshot& c) noexcept {
    c.tick = s.tick;
    c.time = s.timeSeconds;
    put(s.probe, c.probe);
    put(s.proxy, c.proxy);
    put(s.force, c.force);
    put(s.energyForce, c.energy_force);
    put(s.proxyForce, c.proxy_force);
    c.stiffness = s.stiffness;
    c.ray_length = s.rayLength;
    c.distance = s.distance;
    c.coupling_energy = s.couplingEnergy;
    c.observer_energy = s.observerEnergy;
    c.added_damping = s.addedDamping;
    c.contact_count = s.contactCount;
    c.rays = s.rays;
    c.sticking = s.sticking ? 1 : 0;
    c.gate_open = s.gateOpen ? 1 : 0;
    c.faulted = s.faulted ? 1 : 0;
    c.clamped = s.clamped ? 1 : 0;
    c.fading = s.fading ? 1 : 0;
    c.mode = fromMode(s.mode);
    c.faults = s.faults;
    c.stiffness_limited = s.stiffnessLimited ? 1 : 0;
}

palp_latency toC(const ph::LatencySummary& l) noexcept {
    palp_latency c;
    c.p50 = l.p50;
    c.p99 = l.p99;
    c.p999 = l.p999;
    c.max = l.max;
    c.mean = l.mean;
    c.count = l.count;
    return c;
}

}  // namespace

extern "C" {

const char* palp_version(void) { return "0.1.0"; }

const char* palp_status_string(palp_status status) {
    switch (status) {
        case PALP_OK:
            return "PALP_OK";
        case PALP_ERROR_INVALID_ARGUMENT:
            return "PALP_ERROR_INVALID_ARGUMENT";
        case PALP_ERROR_IO:
            return "PALP_ERROR_IO";
        case PALP_ERROR_FORMAT:
            return "PALP_ERROR_FORMAT";
        case PALP_ERROR_STATE:
            return "PALP_ERROR_STATE";
        case PALP_ERROR_QUEUE_FULL:
            return "PALP_ERROR_QUEUE_FULL";
        case PALP_ERROR_OUT_OF_MEMORY:
            return "PALP_ERROR_OUT_OF_MEMORY";
        case PALP_ERROR_REALTIME:
            return "PALP_ERROR_REALTIME";
        case PALP_ERROR_INTERNAL:
            return "PALP_ERROR_INTERNAL";
    }
    return "PALP_ERROR_UNKNOWN";
}

const char* palp_last_error(void) { return tLastError.c_str(); }

void palp_set_error_callback(palp_error_callback callback, void* user) {
    std::lock_guard<std::mutex> lock(gCallbackMutex);
    gCallback = callback;
    gCallbackUser = user;
}

// --- volumes ---------------------------------------------------------------------------

palp_status palp_volume_load(const char* path, double voxel_size, palp_volume** out) {
    if (!path) return nullArgument("palp_volume_load", "path");
    if (!out) return nullArgument("palp_volume_load", "out");
    return guarded([&] {
        if (!(voxel_size >= 0) || !std::isfinite(voxel_size)) {
            throw palp::ValueError(std::string(path) +
                                   ": expected voxel_size >= 0 (0: default), found " +
                                   str(voxel_size));
        }
        pv::LoadOptions options;
        if (voxel_size > 0) options.resample.voxelSize = voxel_size;
        auto handle = std::make_unique<palp_volume>();
        handle->volume = pv::load({std::filesystem::path(path)}, options);
        *out = handle.release();
        return PALP_OK;
    });
}

palp_status palp_volume_make_phantom(const char* scene, int variant, const char* shape,
                                     double voxel_size, palp_volume** out) {
    if (!scene) return nullArgument("palp_volume_make_phantom", "scene");
    if (!out) return nullArgument("palp_volume_make_phantom", "out");
    return guarded([&] {
        pv::PhantomSpec spec;
        spec.params.scene = pv::parseScene(scene);
        if (spec.params.scene == pv::PhantomScene::Avc) spec.params.quadrant = variant;
        if (spec.params.scene == pv::PhantomScene::Bone) spec.params.displacement = variant;
        if (spec.params.scene == pv::PhantomScene::Avcec && shape) {
            spec.params.shape = pv::parseShape(shape);
        }
        if (!(voxel_size > 0) || !std::isfinite(voxel_size)) {
            throw palp::ValueError("palp_volume_make_phantom: expected voxel_size > 0, found " +
                                   str(voxel_size));
        }
        spec.voxelSize = voxel_size;
        auto handle = std::make_unique<palp_volume>();
        handle->volume = pv::makePhantomVolume(spec);
        *out = handle.release();
        return PALP_OK;
    });
}

palp_status palp_volume_geometry(const palp_volume* volume, double* voxel_size,
                                 double bounds_min[3], double bounds_max[3]) {
    if (!volume) return nullArgument("palp_volume_geometry", "volume");
    return guarded([&] {
        if (voxel_size) *voxel_size = volume->volume.voxelSize();
        const openvdb::BBoxd b = volume->volume.worldBounds();
        for (int i = 0; i < 3; ++i) {
            if (bounds_min) bounds_min[i] = b.min()[i];
            if (bounds_max) bounds_max[i] = b.max()[i];
        }
        return PALP_OK;
    });
}

palp_volume* palp_volume_retain(palp_volume* volume) { return retain(volume); }
void palp_volume_release(palp_volume* volume) { release(volume); }

// --- scenes ----------------------------------------------------------------------------

palp_status palp_scene_from_volume(const palp_volume* volume, double surface_iso, double hard_iso,
                                   palp_scene** out) {
    if (!volume) return nullArgument("palp_scene_from_volume", "volume");
    if (!out) return nullArgument("palp_scene_from_volume", "out");
    return guarded([&] {
        ph::SceneOptions options;
        options.surfaceIso = surface_iso;
        options.hardIso = hard_iso;
        auto handle = std::make_unique<palp_scene>();
        handle->scene = ph::Scene::fromVolume(volume->volume, options);
        *out = handle.release();
        return PALP_OK;
    });
}

palp_status palp_scene_create_empty(palp_scene** out) {
    if (!out) return nullArgument("palp_scene_create_empty", "out");
    return guarded([&] {
        auto scene = std::make_shared<ph::Scene>();
        scene->commit();
        auto handle = std::make_unique<palp_scene>();
        handle->scene = std::move(scene);
        *out = handle.release();
        return PALP_OK;
    });
}

palp_scene* palp_scene_retain(palp_scene* scene) { return retain(scene); }
void palp_scene_release(palp_scene* scene) { release(scene); }

// --- sessions --------------------------------------------------------------------------

void palp_session_params_default(palp_session_params* params) {
    if (!params) return;
    const ph::SessionParams d;
    palp_session_params& p = *params;
    std::memset(&p, 0, sizeof p);
    p.mode = fromMode(d.coupling.mode);
    p.source = fromSource(d.coupling.source);
    p.stiffness = d.coupling.baseStiffness;
    p.reference_length = d.coupling.referenceLength;
    p.max_multiplier = d.coupling.maxMultiplier;
    p.max_stiffness = d.coupling.maxStiffness;
    p.damping = d.coupling.damping;
    p.ray_length = d.coupling.bundle.length;
    p.ring_count = d.coupling.bundle.ringCount;
    p.ring_half_angle = d.coupling.bundle.ringHalfAngle;
    p.sobel_angle = d.coupling.bundle.sobelAngle;
    p.surface_offset = d.coupling.bundle.surfaceOffset;
    p.threshold = d.coupling.firstHit.threshold;
    p.ray_step = d.coupling.firstHit.step;
    p.hardness = 1e4;  // 1/m: tau reaches 1 within 0.1 mm of hard material (first-hit-like)
    p.tau_stop = d.coupling.accumulate.tauStop;
    p.static_friction = d.proxy.staticFriction;
    p.dynamic_friction = d.proxy.dynamicFriction;
    p.device = "3D Systems Touch X";
    p.passivity_control = d.passivityControl ? 1 : 0;
    p.period = d.servo.periodSeconds;
    p.startup_threshold = d.startupThresholdN;
    p.startup_quiet_ticks = d.startupQuietTicks;
    p.cross_fade_seconds = d.crossFadeSeconds;
    p.workspace_scale = d.workspace.scale;
    for (int r = 0; r < 3; ++r) {
        for (int c = 0; c < 3; ++c) p.workspace_rotation[3 * r + c] = d.workspace.rotation(r, c);
    }
    put(d.workspace.offset, p.workspace_offset);
    p.trace_capacity = d.traceCapacity;
    p.servo_cpu = d.servo.cpu;
    p.servo_priority = d.servo.priority;
    p.require_realtime = d.servo.requireRealtime ? 1 : 0;
}

palp_status palp_trajectory_default(palp_trajectory_kind kind, palp_trajectory* trajectory) {
    if (!trajectory) return nullArgument("palp_trajectory_default", "trajectory");
    palp_trajectory c;
    std::memset(&c, 0, sizeof c);
    // Every field gets a sensible value from some kind; the chosen kind's own defaults last.
    fill(ph::PressTrajectory{}, c);
    fill(ph::SweepTrajectory{}, c);
    fill(ph::RasterTrajectory{}, c);
    fill(ph::CircleTrajectory{}, c);
    fill(ph::SinusoidTrajectory{}, c);
    if (!forKind(kind, [&](const auto& defaults) { fill(defaults, c); })) {
        return fail(PALP_ERROR_INVALID_ARGUMENT,
                    "palp_trajectory_default: expected PALP_TRAJECTORY_PRESS .. _SINUSOID, "
                    "found an unknown kind");
    }
    c.kind = kind;
    const ph::HandModel hand;
    c.hand_mass = hand.massKg;
    c.hand_stiffness = hand.stiffnessNpm;
    c.hand_damping = hand.dampingNspm;
    *trajectory = c;
    return PALP_OK;
}

palp_status palp_session_create_simulated(palp_scene* scene, const palp_session_params* params,
                                          const palp_trajectory* trajectory, palp_session** out) {
    if (!scene) return nullArgument("palp_session_create_simulated", "scene");
    if (!params) return nullArgument("palp_session_create_simulated", "params");
    if (!trajectory) return nullArgument("palp_session_create_simulated", "trajectory");
    if (!out) return nullArgument("palp_session_create_simulated", "out");
    return guarded([&] {
        const ph::DeviceSpec& spec = deviceSpec(params->device);
        const ph::SessionParams sp = toSession(*params);
        const ph::Trajectory path = toTrajectory(*trajectory);
        const ph::HandModel hand = toHand(*trajectory);
        auto handle = std::make_unique<palp_session>();
        handle->deviceName = params->device;
        handle->params = *params;
        handle->params.device = handle->deviceName.c_str();
        handle->device = makeDevice(spec, path, hand, sp.servo.periodSeconds);
        handle->session = std::make_unique<ph::Session>(scene->scene, *handle->device, sp);
        // The stiffness in force: lowered to the device's limit when above it.
        handle->params.stiffness = handle->session->params().coupling.baseStiffness;
        handle->params.max_stiffness = handle->session->params().coupling.maxStiffness;
        *out = handle.release();
        return PALP_OK;
    });
}

palp_session* palp_session_retain(palp_session* session) { return retain(session); }
void palp_session_release(palp_session* session) { release(session); }

palp_status palp_session_start(palp_session* session) {
    if (!session) return nullArgument("palp_session_start", "session");
    if (session->session->running()) {
        return fail(PALP_ERROR_STATE,
                    "palp_session_start: expected a stopped session, found it running");
    }
    return guarded([&] {
        try {
            session->session->start();
        } catch (const palp::ValueError&) {
            throw;
        } catch (const palp::Error& e) {
            bool requireRealtime = false;
            {
                const std::lock_guard<std::mutex> lock(session->paramsMutex);
                requireRealtime = session->params.require_realtime != 0;
            }
            return fail(requireRealtime ? PALP_ERROR_REALTIME : PALP_ERROR_STATE, e.what());
        }
        return PALP_OK;
    });
}

palp_status palp_session_stop(palp_session* session) {
    if (!session) return nullArgument("palp_session_stop", "session");
    session->session->stop();
    return PALP_OK;
}

int palp_session_running(const palp_session* session) {
    return session && session->session->running() ? 1 : 0;
}

palp_status palp_session_step(palp_session* session, uint32_t ticks, palp_snapshot* last) {
    if (!session) return nullArgument("palp_session_step", "session");
    if (session->session->running()) {
        return fail(PALP_ERROR_STATE,
                    "palp_session_step: expected a stopped session, found its servo thread "
                    "running (call palp_session_stop first)");
    }
    const ph::Snapshot* s = nullptr;
    for (uint32_t i = 0; i < ticks; ++i) s = &session->session->step();
    if (last && s) toC(*s, *last);
    return PALP_OK;
}

palp_status palp_session_latest(palp_session* session, palp_snapshot* out) {
    if (!session) return nullArgument("palp_session_latest", "session");
    if (!out) return nullArgument("palp_session_latest", "out");
    toC(session->session->latest(), *out);
    return PALP_OK;
}

palp_status palp_session_pop_trace(palp_session* session, palp_snapshot* out, int* got) {
    if (!session) return nullArgument("palp_session_pop_trace", "session");
    if (!out) return nullArgument("palp_session_pop_trace", "out");
    if (!got) return nullArgument("palp_session_pop_trace", "got");
    ph::Snapshot s;
    *got = session->session->popTrace(s) ? 1 : 0;
    if (*got) toC(s, *out);
    return PALP_OK;
}

palp_status palp_session_set_params(palp_session* session, const palp_session_params* params) {
    if (!session) return nullArgument("palp_session_set_params", "session");
    if (!params) return nullArgument("palp_session_set_params", "params");
    return guarded([&] {
        const std::lock_guard<std::mutex> lock(session->paramsMutex);
        if (const char* field = fixedFieldChanged(session->params, *params)) {
            throw palp::ValueError(std::string("palp_session_set_params: expected ") + field +
                                   " to stay as at creation (it cannot change while a session "
                                   "exists), found a different value");
        }
        // One SetAll command: the coupling, friction and passivity changes take one queue slot
        // and land on the same tick, so a full queue refuses all of them (all or nothing).
        ph::Command all;
        all.kind = ph::Command::Kind::SetAll;
        all.coupling = toCoupling(*params);
        all.proxy = toProxy(*params);
        all.flag = params->passivity_control != 0;
        ph::CouplingParams inForce = all.coupling;  // what the session renders (see send())
        ph::limitStiffnessToDevice(inForce, session->session->deviceSpec());
        if (!session->session->send(all)) {  // validates everything before queueing anything
            return fail(PALP_ERROR_QUEUE_FULL,
                        "palp_session_set_params: command queue full (nothing applied)");
        }
        palp_session_params& now = session->params;
        const char* device = now.device;
        now = *params;
        now.device = device;
        now.stiffness = inForce.baseStiffness;
        now.max_stiffness = inForce.maxStiffness;
        return PALP_OK;
    });
}

palp_status palp_session_set_mode(palp_session* session, palp_coupling_mode mode) {
    if (!session) return nullArgument("palp_session_set_mode", "session");
    return guarded([&] {
        const std::lock_guard<std::mutex> lock(session->paramsMutex);
        palp_session_params p = session->params;
        p.mode = mode;
        ph::Command c;
        c.kind = ph::Command::Kind::SetCoupling;
        c.coupling = toCoupling(p);
        if (!session->session->send(c)) {
            return fail(PALP_ERROR_QUEUE_FULL, "palp_session_set_mode: command queue full");
        }
        session->params.mode = mode;
        return PALP_OK;
    });
}

palp_status palp_session_get_params(const palp_session* session, palp_session_params* out) {
    if (!session) return nullArgument("palp_session_get_params", "session");
    if (!out) return nullArgument("palp_session_get_params", "out");
    const std::lock_guard<std::mutex> lock(session->paramsMutex);
    *out = session->params;
    return PALP_OK;
}

palp_status palp_session_reset_observer(palp_session* session) {
    if (!session) return nullArgument("palp_session_reset_observer", "session");
    return guarded([&] {
        ph::Command c;
        c.kind = ph::Command::Kind::ResetObserver;
        if (!session->session->send(c)) {
            return fail(PALP_ERROR_QUEUE_FULL, "palp_session_reset_observer: command queue full");
        }
        return PALP_OK;
    });
}

palp_status palp_session_stats(const palp_session* session, palp_loop_stats* out) {
    if (!session) return nullArgument("palp_session_stats", "session");
    if (!out) return nullArgument("palp_session_stats", "out");
    const ph::ServoStats s = session->session->stats();
    out->wake_latency = toC(s.wakeLatency);
    out->period_error = toC(s.periodError);
    out->compute = toC(s.compute);
    out->ticks = s.ticks;
    out->misses = s.misses;
    out->skipped = s.skipped;
    out->trace_dropped = session->session->traceDropped();
    return PALP_OK;
}

palp_status palp_session_realtime(const palp_session* session, palp_realtime* out) {
    if (!session) return nullArgument("palp_session_realtime", "session");
    if (!out) return nullArgument("palp_session_realtime", "out");
    const ph::RealtimeStatus& r = session->session->realtime();
    out->pinned = r.pinned ? 1 : 0;
    out->cpu = r.cpu;
    out->fifo = r.fifo ? 1 : 0;
    out->priority = r.priority;
    out->memory_locked = r.memoryLocked ? 1 : 0;
    out->failed = r.failed ? 1 : 0;
    out->message = r.message.c_str();
    return PALP_OK;
}

const char* palp_session_realtime_status(const palp_session* session) {
    return session ? session->session->realtime().message.c_str() : nullptr;
}

}  // extern "C"
