// The C API's conversions (see c_api_internal.h): session parameters, trajectories (one table
// per kind) and snapshots between the plain C structs of palp/palp.h and palp::haptics, and
// the C defaults.

#include <Eigen/LU>
#include <array>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <string>
#include <type_traits>

#include "c_api_internal.h"
#include "palp/base/bounds.h"
#include "palp/base/validate.h"

namespace ph = palp::haptics;

namespace palp::capi {
namespace {

ph::CouplingMode toMode(int m) {
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
        std::to_string(m));
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

ph::RaySource toSource(int s) {
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
        std::to_string(s));
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

// --- trajectories ------------------------------------------------------------------------
//
// Each kind's C <-> C++ correspondence is written once, as a table of (C field, C++ member,
// check); palp_trajectory_default (fill) and toTrajectory (convert) both walk it. Vectors come
// first, then scalars, each in table order: the first invalid field is the one reported.

enum class Check : std::uint8_t {
    Point,  // vector: coordinates within bounds::kPosition
    Unit    // vector: finite and non-zero, normalised
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
    const Bounds* bounds;  // palp/base/bounds.h
};

template <typename T>
struct Layout;

template <>
struct Layout<ph::PressTrajectory> {
    using T = ph::PressTrajectory;
    static constexpr std::array vectors = {
        VectorField<T>{&palp_trajectory::centre, &T::start, "centre", Check::Point},
        VectorField<T>{&palp_trajectory::direction, &T::direction, "direction", Check::Unit}};
    static constexpr std::array scalars = {
        ScalarField<T>{&palp_trajectory::depth, &T::depthM, "depth", &bounds::kSpan},
        ScalarField<T>{&palp_trajectory::press_seconds, &T::pressSeconds, "press_seconds",
                       &bounds::kPositiveDuration},
        ScalarField<T>{&palp_trajectory::hold_seconds, &T::holdSeconds, "hold_seconds",
                       &bounds::kDuration}};
};

template <>
struct Layout<ph::SweepTrajectory> {
    using T = ph::SweepTrajectory;
    static constexpr std::array vectors = {
        VectorField<T>{&palp_trajectory::centre, &T::centre, "centre", Check::Point},
        VectorField<T>{&palp_trajectory::direction, &T::direction, "direction", Check::Unit},
        VectorField<T>{&palp_trajectory::press_direction, &T::pressDirection, "press_direction",
                       Check::Unit}};
    static constexpr std::array scalars = {
        ScalarField<T>{&palp_trajectory::length, &T::lengthM, "length", &bounds::kLength},
        ScalarField<T>{&palp_trajectory::speed, &T::speedMps, "speed", &bounds::kPositiveSpeed},
        ScalarField<T>{&palp_trajectory::depth, &T::depthM, "depth", &bounds::kSpan},
        ScalarField<T>{&palp_trajectory::approach, &T::approachM, "approach", &bounds::kSpan},
        ScalarField<T>{&palp_trajectory::approach_seconds, &T::approachSeconds, "approach_seconds",
                       &bounds::kPositiveDuration},
        ScalarField<T>{&palp_trajectory::turn_seconds, &T::turnSeconds, "turn_seconds",
                       &bounds::kPositiveDuration}};
};

template <>
struct Layout<ph::RasterTrajectory> {
    using T = ph::RasterTrajectory;
    static constexpr std::array vectors = {
        VectorField<T>{&palp_trajectory::centre, &T::centre, "centre", Check::Point},
        VectorField<T>{&palp_trajectory::u, &T::u, "u", Check::Unit},
        VectorField<T>{&palp_trajectory::v, &T::v, "v", Check::Unit},
        VectorField<T>{&palp_trajectory::press_direction, &T::pressDirection, "press_direction",
                       Check::Unit}};
    static constexpr std::array scalars = {
        ScalarField<T>{&palp_trajectory::extent_u, &T::extentU, "extent_u", &bounds::kLength},
        ScalarField<T>{&palp_trajectory::extent_v, &T::extentV, "extent_v", &bounds::kSpan},
        ScalarField<T>{&palp_trajectory::line_spacing, &T::lineSpacingM, "line_spacing",
                       &bounds::kLength},
        ScalarField<T>{&palp_trajectory::speed, &T::speedMps, "speed", &bounds::kPositiveSpeed},
        ScalarField<T>{&palp_trajectory::depth, &T::depthM, "depth", &bounds::kSpan},
        ScalarField<T>{&palp_trajectory::approach, &T::approachM, "approach", &bounds::kSpan},
        ScalarField<T>{&palp_trajectory::approach_seconds, &T::approachSeconds, "approach_seconds",
                       &bounds::kPositiveDuration}};
};

template <>
struct Layout<ph::CircleTrajectory> {
    using T = ph::CircleTrajectory;
    static constexpr std::array vectors = {
        VectorField<T>{&palp_trajectory::centre, &T::centre, "centre", Check::Point},
        VectorField<T>{&palp_trajectory::u, &T::u, "u", Check::Unit},
        VectorField<T>{&palp_trajectory::v, &T::v, "v", Check::Unit},
        VectorField<T>{&palp_trajectory::press_direction, &T::pressDirection, "press_direction",
                       Check::Unit}};
    static constexpr std::array scalars = {
        ScalarField<T>{&palp_trajectory::radius, &T::radiusM, "radius", &bounds::kSpan},
        ScalarField<T>{&palp_trajectory::frequency, &T::frequencyHz, "frequency",
                       &bounds::kFrequency},
        ScalarField<T>{&palp_trajectory::depth, &T::depthM, "depth", &bounds::kSpan},
        ScalarField<T>{&palp_trajectory::approach, &T::approachM, "approach", &bounds::kSpan},
        ScalarField<T>{&palp_trajectory::approach_seconds, &T::approachSeconds, "approach_seconds",
                       &bounds::kPositiveDuration}};
};

template <>
struct Layout<ph::SinusoidTrajectory> {
    using T = ph::SinusoidTrajectory;
    static constexpr std::array vectors = {
        VectorField<T>{&palp_trajectory::centre, &T::start, "centre", Check::Point},
        VectorField<T>{&palp_trajectory::direction, &T::direction, "direction", Check::Unit}};
    static constexpr std::array scalars = {
        ScalarField<T>{&palp_trajectory::amplitude, &T::amplitudeM, "amplitude", &bounds::kSpan},
        ScalarField<T>{&palp_trajectory::frequency, &T::frequencyHz, "frequency",
                       &bounds::kFrequency},
        ScalarField<T>{&palp_trajectory::grow_seconds, &T::growSeconds, "grow_seconds",
                       &bounds::kDuration}};
};

// Calls @p f with a default-constructed trajectory of @p kind; false for an unknown kind.
template <typename F>
bool forKind(int kind, F&& f) {
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
        throwExpected(
            std::string("palp_trajectory.") + field, "a finite non-zero vector",
            "(" + formatValue(v[0]) + ", " + formatValue(v[1]) + ", " + formatValue(v[2]) + ")");
    }
    return d / n;
}

Eigen::Vector3d point(const double v[3], const char* field) {
    for (int i = 0; i < 3; ++i) {
        requireWithin(std::string("palp_trajectory.") + field + "[" + std::to_string(i) + "]", v[i],
                      bounds::kPosition);
    }
    return vec(v);
}

void requireField(const char* field, double v, const Bounds& b) {
    requireWithin(std::string("palp_trajectory.") + field, v, b);
}

// C -> C++ for the kind of T, checking every field. @throw palp::ValueError naming the field.
template <typename T>
T convert(const palp_trajectory& c) {
    T t;
    for (const VectorField<T>& f : Layout<T>::vectors) {
        t.*f.t = f.check == Check::Unit ? unit(c.*f.c, f.name) : point(c.*f.c, f.name);
    }
    for (const ScalarField<T>& f : Layout<T>::scalars) {
        requireField(f.name, c.*f.c, *f.bounds);
        t.*f.t = c.*f.c;
    }
    return t;
}

}  // namespace

// --- session parameters ----------------------------------------------------------------

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

namespace {

/// Every number of palp_session_params with its bounds (palp/base/bounds.h), checked in this
/// order before any conversion, so a refusal names the C field.
struct ParamField {
    double palp_session_params::*field;
    const char* name;
    const Bounds* bounds;
};

constexpr std::array kParamFields = {
    ParamField{&palp_session_params::stiffness, "stiffness", &bounds::kPositiveStiffness},
    ParamField{&palp_session_params::reference_length, "reference_length", &bounds::kLength},
    ParamField{&palp_session_params::max_multiplier, "max_multiplier", &bounds::kMultiplier},
    ParamField{&palp_session_params::max_stiffness, "max_stiffness", &bounds::kPositiveStiffness},
    ParamField{&palp_session_params::damping, "damping", &bounds::kDamping},
    ParamField{&palp_session_params::ray_length, "ray_length", &bounds::kLength},
    ParamField{&palp_session_params::ring_half_angle, "ring_half_angle", &bounds::kAngle},
    ParamField{&palp_session_params::ring_weight_sigma, "ring_weight_sigma", &bounds::kAngle},
    ParamField{&palp_session_params::sobel_angle, "sobel_angle", &bounds::kAngle},
    ParamField{&palp_session_params::surface_offset, "surface_offset", &bounds::kSpacing},
    ParamField{&palp_session_params::threshold, "threshold", &bounds::kVolumeValue},
    ParamField{&palp_session_params::ray_step, "ray_step", &bounds::kSpacing},
    ParamField{&palp_session_params::hardness, "hardness", &bounds::kHardness},
    ParamField{&palp_session_params::tau_stop, "tau_stop", &bounds::kTauStop},
    ParamField{&palp_session_params::static_friction, "static_friction", &bounds::kFriction},
    ParamField{&palp_session_params::dynamic_friction, "dynamic_friction", &bounds::kFriction},
    ParamField{&palp_session_params::period, "period", &bounds::kPeriod},
    ParamField{&palp_session_params::startup_threshold, "startup_threshold",
               &bounds::kPositiveForce},
    ParamField{&palp_session_params::cross_fade_seconds, "cross_fade_seconds", &bounds::kDuration},
    ParamField{&palp_session_params::workspace_scale, "workspace_scale", &bounds::kScale},
    ParamField{&palp_session_params::recontact_seconds, "recontact_seconds", &bounds::kWindow},
    ParamField{&palp_session_params::recontact_rise_nps, "recontact_rise_nps", &bounds::kForceRate},
    ParamField{&palp_session_params::max_ray_tilt, "max_ray_tilt", &bounds::kRayTilt}};

/// Most quiet start-up ticks asked for (a minute at 1 kHz).
constexpr std::uint32_t kMaxStartupQuietTicks = 60000;

void checkParamFields(const palp_session_params& p) {
    for (const ParamField& f : kParamFields) {
        requireWithin(std::string("palp_session_params.") + f.name, p.*f.field, *f.bounds);
    }
    for (int i = 0; i < 3; ++i) {
        requireWithin("palp_session_params.workspace_offset[" + std::to_string(i) + "]",
                      p.workspace_offset[i], bounds::kPosition);
    }
    Eigen::Matrix3d r;
    for (int i = 0; i < 9; ++i) r(i / 3, i % 3) = p.workspace_rotation[i];
    const double orth = (r.transpose() * r - Eigen::Matrix3d::Identity()).cwiseAbs().maxCoeff();
    const double det = r.determinant();
    if (!(orth <= 1e-6 && std::abs(det - 1.0) <= 1e-6)) {
        throwExpected("palp_session_params.workspace_rotation",
                      "a rotation, row-major (R^T R = I, det 1)",
                      "|R^T R - I| = " + formatValue(orth) + ", det " + formatValue(det));
    }
    if (p.ring_count < 0 || p.ring_count > palp::kernels::kMaxRingRays) {
        throwExpected("palp_session_params.ring_count",
                      "0.." + std::to_string(palp::kernels::kMaxRingRays),
                      std::to_string(p.ring_count));
    }
    if (p.startup_quiet_ticks > kMaxStartupQuietTicks) {
        throwExpected("palp_session_params.startup_quiet_ticks",
                      "at most " + std::to_string(kMaxStartupQuietTicks),
                      std::to_string(p.startup_quiet_ticks));
    }
    if (p.dynamic_friction > p.static_friction) {
        throwExpected("palp_session_params.dynamic_friction",
                      "at most static_friction (" + formatValue(p.static_friction) + ")",
                      formatValue(p.dynamic_friction));
    }
    if (p.max_stiffness < p.stiffness) {
        throwExpected("palp_session_params.max_stiffness",
                      "at least stiffness (" + formatValue(p.stiffness) + " N/m)",
                      formatValue(p.max_stiffness));
    }
}

}  // namespace

ph::CouplingParams toCoupling(const palp_session_params& p) {
    checkParamFields(p);
    ph::CouplingParams c;
    c.mode = toMode(rawEnum(p.mode));
    c.source = toSource(rawEnum(p.source));
    c.baseStiffness = p.stiffness;
    c.referenceLength = p.reference_length;
    c.maxMultiplier = p.max_multiplier;
    c.maxStiffness = p.max_stiffness;
    c.damping = p.damping;
    c.bundle.length = p.ray_length;
    c.bundle.ringCount = p.ring_count;
    c.bundle.ringHalfAngle = p.ring_half_angle;
    c.bundle.ringWeightSigma = p.ring_weight_sigma;
    c.bundle.sobelAngle = p.sobel_angle;
    c.bundle.surfaceOffset = p.surface_offset;
    c.maxRayTilt = p.max_ray_tilt;
    c.firstHit.threshold = static_cast<float>(p.threshold);
    c.firstHit.step = p.ray_step;
    c.accumulate.step = p.ray_step;
    c.accumulate.tauStop = p.tau_stop;
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
    s.recontact.seconds = p.recontact_seconds;
    s.recontact.riseNps = p.recontact_rise_nps;
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
    s.servo.reserveCpu = p.servo_reserve_cpu != 0;
    ph::validateSessionParams(s);
    return s;
}

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
    if ((a.servo_reserve_cpu != 0) != (b.servo_reserve_cpu != 0)) return "servo_reserve_cpu";
    return nullptr;
}

// --- trajectories ------------------------------------------------------------------------

ph::Trajectory toTrajectory(const palp_trajectory& c) {
    point(c.centre, "centre");  // every kind has one; reported before an unknown kind
    ph::Trajectory out;
    if (!forKind(rawEnum(c.kind),
                 [&](const auto& kind) { out = convert<std::decay_t<decltype(kind)>>(c); })) {
        throw palp::ValueError(
            "palp_trajectory.kind: expected PALP_TRAJECTORY_PRESS .. _SINUSOID, found " +
            std::to_string(rawEnum(c.kind)));
    }
    return out;
}

ph::HandModel toHand(const palp_trajectory& c) {
    requireField("hand_mass", c.hand_mass, bounds::kMass);
    requireField("hand_stiffness", c.hand_stiffness, bounds::kStiffness);
    requireField("hand_damping", c.hand_damping, bounds::kDamping);
    ph::HandModel h;
    h.massKg = c.hand_mass;
    h.stiffnessNpm = c.hand_stiffness;
    h.dampingNspm = c.hand_damping;
    return h;
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
    put(s.tissueForce, c.tissue_force);
    c.contact_node = s.contactNode;
    c.max_displacement = s.maxDisplacement;
    c.fem_flags = s.femFlags;
    c.device_stale = s.deviceStale ? 1 : 0;
    c.device_force_scale = s.deviceForceScale;
    c.watchdog_trips = s.watchdogTrips;
    c.passivity_cut = s.passivityCut;
    c.fault_flags = s.faultFlags;
    c.stale_ticks = s.faultCounts.stale;
    c.non_finite_samples = s.faultCounts.nonFinite;
    c.out_of_range_samples = s.faultCounts.outOfRange;
    c.too_fast_samples = s.faultCounts.tooFast;
    c.non_finite_forces = s.faultCounts.forceNonFinite;
    c.force_jumps = s.faultCounts.forceJump;
    c.overload_ticks = s.faultCounts.overload;
    c.fault_trips = s.faultTrips;
}

namespace {
constexpr bool sameBit(palp_fault c, ph::DeviceFault f) noexcept {
    return static_cast<std::uint32_t>(c) == static_cast<std::uint32_t>(f);
}
}  // namespace
static_assert(sameBit(PALP_FAULT_STALE, ph::kFaultStale) &&
                  sameBit(PALP_FAULT_NON_FINITE, ph::kFaultNonFinite) &&
                  sameBit(PALP_FAULT_OUT_OF_RANGE, ph::kFaultOutOfRange) &&
                  sameBit(PALP_FAULT_TOO_FAST, ph::kFaultTooFast) &&
                  sameBit(PALP_FAULT_FORCE_NON_FINITE, ph::kFaultForceNonFinite) &&
                  sameBit(PALP_FAULT_FORCE_JUMP, ph::kFaultForceJump) &&
                  sameBit(PALP_FAULT_OVERLOAD, ph::kFaultOverload) &&
                  sameBit(PALP_FAULT_SHED, ph::kFaultShed),
              "palp.h's PALP_FAULT_* bits are DeviceFault's");

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

void fromSession(const ph::SessionParams& d, palp_session_params& p) noexcept {
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
    p.ring_weight_sigma = d.coupling.bundle.ringWeightSigma;
    p.sobel_angle = d.coupling.bundle.sobelAngle;
    p.surface_offset = d.coupling.bundle.surfaceOffset;
    p.max_ray_tilt = d.coupling.maxRayTilt;
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
    p.recontact_seconds = d.recontact.seconds;
    p.recontact_rise_nps = d.recontact.riseNps;
    p.workspace_scale = d.workspace.scale;
    for (int r = 0; r < 3; ++r) {
        for (int c = 0; c < 3; ++c) p.workspace_rotation[3 * r + c] = d.workspace.rotation(r, c);
    }
    put(d.workspace.offset, p.workspace_offset);
    p.trace_capacity = d.traceCapacity;
    p.servo_cpu = d.servo.cpu;
    p.servo_priority = d.servo.priority;
    p.require_realtime = d.servo.requireRealtime ? 1 : 0;
    p.servo_reserve_cpu = d.servo.reserveCpu ? 1 : 0;
}

}  // namespace palp::capi

using namespace palp::capi;

extern "C" {

void palp_session_params_default(palp_session_params* params) {
    if (!params) return;
    fromSession(ph::SessionParams{}, *params);
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
    if (!forKind(rawEnum(kind), [&](const auto& defaults) { fill(defaults, c); })) {
        return fail(PALP_ERROR_INVALID_ARGUMENT,
                    "palp_trajectory_default: expected PALP_TRAJECTORY_PRESS .. _SINUSOID, "
                    "found an unknown kind");
    }
    std::memcpy(&c.kind, &kind, sizeof kind);  // checked above, but never loaded unchecked
    const ph::HandModel hand;
    c.hand_mass = hand.massKg;
    c.hand_stiffness = hand.stiffnessNpm;
    c.hand_damping = hand.dampingNspm;
    *trajectory = c;
    return PALP_OK;
}

}  // extern "C"
