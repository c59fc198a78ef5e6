// libFuzzer target for the C API's session and trajectory structs: the input overwrites fields
// of palp_session_params and palp_trajectory (defaults first) with arbitrary doubles and
// integers, then creates a simulated session on the AVC phantom, steps it a bounded number of
// ticks, changes its parameters at run time and releases it. Whatever the input, palp must
// answer with a status: no abort (Embree's and Eigen's assertions included), no hang, no
// sanitizer report. Run with tools/fuzz/run_fuzzers.sh.

#include <cmath>
#include <cstddef>
#include <cstdint>
#include <cstdlib>
#include <cstring>

#include "palp/palp.h"

namespace {

/// Reads the fuzzer's bytes in order; past the end every read is zero.
class Input {
  public:
    Input(const std::uint8_t* data, std::size_t size) : mData(data), mSize(size) {}
    bool more() const { return mPos < mSize; }
    std::uint8_t byte() { return mPos < mSize ? mData[mPos++] : 0; }
    /// Half the time a raw double (NaN, inf, 1e300, denormals), half a plausible one: a 16-bit
    /// integer times a power of ten from 1e-6 to 1e3, so in-range values are reached too.
    double number() {
        if (byte() & 1) {
            std::uint64_t bits = 0;
            for (int i = 0; i < 8; ++i) bits = (bits << 8) | byte();
            double v;
            std::memcpy(&v, &bits, sizeof v);
            return v;
        }
        const auto raw = static_cast<std::int16_t>((byte() << 8) | byte());
        static const double scales[] = {1e-6, 1e-5, 1e-4, 1e-3, 1e-2, 1e-1, 1, 10, 100, 1e3};
        return raw * scales[byte() % 10];
    }
    int integer() {
        std::uint32_t v = 0;
        for (int i = 0; i < 4; ++i) v = (v << 8) | byte();
        return static_cast<int>(v);
    }

  private:
    const std::uint8_t* mData;
    std::size_t mSize;
    std::size_t mPos = 0;
};

double* paramDouble(palp_session_params& p, unsigned i) {
    double* const fields[] = {&p.stiffness,
                              &p.reference_length,
                              &p.max_multiplier,
                              &p.max_stiffness,
                              &p.damping,
                              &p.ray_length,
                              &p.ring_half_angle,
                              &p.sobel_angle,
                              &p.surface_offset,
                              &p.max_ray_tilt,
                              &p.threshold,
                              &p.ray_step,
                              &p.hardness,
                              &p.tau_stop,
                              &p.static_friction,
                              &p.dynamic_friction,
                              &p.period,
                              &p.startup_threshold,
                              &p.cross_fade_seconds,
                              &p.workspace_scale,
                              &p.workspace_rotation[i % 9],
                              &p.workspace_offset[i % 3]};
    return fields[i % (sizeof fields / sizeof fields[0])];
}

double* trajectoryDouble(palp_trajectory& t, unsigned i) {
    double* const fields[] = {&t.centre[i % 3],
                              &t.direction[i % 3],
                              &t.press_direction[i % 3],
                              &t.u[i % 3],
                              &t.v[i % 3],
                              &t.depth,
                              &t.length,
                              &t.extent_u,
                              &t.extent_v,
                              &t.line_spacing,
                              &t.speed,
                              &t.radius,
                              &t.frequency,
                              &t.amplitude,
                              &t.grow_seconds,
                              &t.press_seconds,
                              &t.hold_seconds,
                              &t.approach,
                              &t.approach_seconds,
                              &t.turn_seconds,
                              &t.hand_mass,
                              &t.hand_stiffness,
                              &t.hand_damping};
    return fields[i % (sizeof fields / sizeof fields[0])];
}

void setParamInteger(palp_session_params& p, unsigned i, int v) {
    switch (i % 6) {
        case 0:  // any int, as a C caller may store in an enum (palp reads it as bytes)
            std::memcpy(&p.mode, &v, sizeof v);
            break;
        case 1:
            std::memcpy(&p.source, &v, sizeof v);
            break;
        case 2:
            p.ring_count = v;
            break;
        case 3:
            p.passivity_control = v & 1;
            break;
        case 4:
            p.startup_quiet_ticks = static_cast<std::uint32_t>(v);
            break;
        default:
            p.trace_capacity = static_cast<std::uint32_t>(v) % 4096;
            break;
    }
}

palp_scene* scene() {
    static palp_scene* s = [] {
        palp_volume* volume = nullptr;
        palp_scene* made = nullptr;
        if (palp_volume_make_phantom("avc", 0, nullptr, 2e-3, &volume) != PALP_OK) std::abort();
        if (palp_scene_from_volume(volume, -500.0, 500.0, &made) != PALP_OK) std::abort();
        palp_volume_release(volume);
        return made;
    }();
    return s;
}

/// Applies edits from @p in to @p p and @p t until a stop byte (0) or the end.
void edit(Input& in, palp_session_params& p, palp_trajectory& t) {
    while (in.more()) {
        const std::uint8_t op = in.byte();
        if (op == 0) return;
        const unsigned which = in.byte();
        switch (op % 3) {
            case 0:
                *paramDouble(p, which) = in.number();
                break;
            case 1:
                *trajectoryDouble(t, which) = in.number();
                break;
            default:
                setParamInteger(p, which, in.integer());
                break;
        }
    }
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
    Input in(data, size);
    const auto kind = static_cast<palp_trajectory_kind>(in.byte() % 5);
    palp_session_params p;
    palp_session_params_default(&p);
    p.servo_cpu = -1;
    p.servo_priority = 0;  // offline stepping only; never ask for SCHED_FIFO here
    palp_trajectory t;
    if (palp_trajectory_default(kind, &t) != PALP_OK) std::abort();
    edit(in, p, t);
    palp_session* session = nullptr;
    const palp_status st = palp_session_create_simulated(scene(), &p, &t, &session);
    if (st == PALP_ERROR_INTERNAL) std::abort();  // a bug: every input deserves a real answer
    if (st != PALP_OK) {
        if (session != nullptr) std::abort();
        return 0;
    }
    palp_snapshot s;
    // Bounded work: 60 ticks, a run-time change, 60 more.
    if (palp_session_step(session, 60, &s) == PALP_ERROR_INTERNAL) std::abort();
    palp_session_params q = p;
    palp_trajectory unused = t;
    edit(in, q, unused);
    if (palp_session_set_params(session, &q) == PALP_ERROR_INTERNAL) std::abort();
    if (palp_session_step(session, 60, &s) == PALP_ERROR_INTERNAL) std::abort();
    palp_session_release(session);
    return 0;
}
