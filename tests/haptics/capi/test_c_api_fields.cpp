// Every number field of the C API's palp_session_params and palp_trajectory (each kind), given
// nan, inf, -inf, -1, 0 and 1e300 on a session over the AVC phantom: palp_session_create_simulated
// either refuses it (PALP_ERROR_INVALID_ARGUMENT, the message naming the field) or accepts it
// where the field's range admits the value, and then the session steps (PALP_OK, finite
// snapshots). Never an abort (Embree's ray assertions took the process down for a 1e300 centre),
// never PALP_ERROR_INTERNAL. The same goes for palp_session_set_params on a live session.

#include <gtest/gtest.h>

#include <cmath>
#include <cstring>
#include <limits>
#include <set>
#include <string>
#include <utility>
#include <vector>

#include "palp/palp.h"

namespace {

const std::vector<double> kBadValues = {std::nan(""),
                                        std::numeric_limits<double>::infinity(),
                                        -std::numeric_limits<double>::infinity(),
                                        -1.0,
                                        0.0,
                                        1e300};

std::string show(double v) {
    char buf[32];
    std::snprintf(buf, sizeof buf, "%g", v);
    return buf;
}

/// A field: its C name, where it lives in the struct, and how many doubles it holds.
template <typename S>
struct Field {
    const char* name;
    double* (*at)(S&);
    int count = 1;
};

#define PALP_FIELD(S, f)                  \
    Field<S> {                            \
#f, [](S & s) { return &s.f; }, 1 \
    }
#define PALP_ARRAY(S, f, n)                  \
    Field<S> {                               \
#f, [](S & s) { return &s.f[0]; }, n \
    }

// When a field is added to palp.h, these sizes change: add it to the tables below.
static_assert(sizeof(palp_session_params) == 344, "palp_session_params changed: update the table");
static_assert(sizeof(palp_trajectory) == 272, "palp_trajectory changed: update the table");

const std::vector<Field<palp_session_params>> kParamFields = {
    PALP_FIELD(palp_session_params, stiffness),
    PALP_FIELD(palp_session_params, reference_length),
    PALP_FIELD(palp_session_params, max_multiplier),
    PALP_FIELD(palp_session_params, max_stiffness),
    PALP_FIELD(palp_session_params, damping),
    PALP_FIELD(palp_session_params, ray_length),
    PALP_FIELD(palp_session_params, ring_half_angle),
    PALP_FIELD(palp_session_params, ring_weight_sigma),
    PALP_FIELD(palp_session_params, sobel_angle),
    PALP_FIELD(palp_session_params, surface_offset),
    PALP_FIELD(palp_session_params, threshold),
    PALP_FIELD(palp_session_params, ray_step),
    PALP_FIELD(palp_session_params, hardness),
    PALP_FIELD(palp_session_params, tau_stop),
    PALP_FIELD(palp_session_params, static_friction),
    PALP_FIELD(palp_session_params, dynamic_friction),
    PALP_FIELD(palp_session_params, period),
    PALP_FIELD(palp_session_params, startup_threshold),
    PALP_FIELD(palp_session_params, cross_fade_seconds),
    PALP_FIELD(palp_session_params, workspace_scale),
    PALP_ARRAY(palp_session_params, workspace_rotation, 9),
    PALP_ARRAY(palp_session_params, workspace_offset, 3),
    PALP_FIELD(palp_session_params, recontact_seconds),
    PALP_FIELD(palp_session_params, recontact_rise_nps),
    PALP_FIELD(palp_session_params, max_ray_tilt)};

const std::vector<Field<palp_trajectory>> kTrajectoryFields = {
    PALP_ARRAY(palp_trajectory, centre, 3),
    PALP_ARRAY(palp_trajectory, direction, 3),
    PALP_ARRAY(palp_trajectory, press_direction, 3),
    PALP_ARRAY(palp_trajectory, u, 3),
    PALP_ARRAY(palp_trajectory, v, 3),
    PALP_FIELD(palp_trajectory, depth),
    PALP_FIELD(palp_trajectory, length),
    PALP_FIELD(palp_trajectory, extent_u),
    PALP_FIELD(palp_trajectory, extent_v),
    PALP_FIELD(palp_trajectory, line_spacing),
    PALP_FIELD(palp_trajectory, speed),
    PALP_FIELD(palp_trajectory, radius),
    PALP_FIELD(palp_trajectory, frequency),
    PALP_FIELD(palp_trajectory, amplitude),
    PALP_FIELD(palp_trajectory, grow_seconds),
    PALP_FIELD(palp_trajectory, press_seconds),
    PALP_FIELD(palp_trajectory, hold_seconds),
    PALP_FIELD(palp_trajectory, approach),
    PALP_FIELD(palp_trajectory, approach_seconds),
    PALP_FIELD(palp_trajectory, turn_seconds),
    PALP_FIELD(palp_trajectory, hand_mass),
    PALP_FIELD(palp_trajectory, hand_stiffness),
    PALP_FIELD(palp_trajectory, hand_damping)};

/// The AVC phantom at 2 mm and its scene, shared by every case.
class CApiFields : public ::testing::Test {
  protected:
    static void SetUpTestSuite() {
        palp_volume* volume = nullptr;
        ASSERT_EQ(palp_volume_make_phantom("avc", 0, nullptr, 2e-3, &volume), PALP_OK)
            << palp_last_error();
        ASSERT_EQ(palp_scene_from_volume(volume, -500.0, 500.0, &sScene), PALP_OK)
            << palp_last_error();
        palp_volume_release(volume);
    }
    static void TearDownTestSuite() {
        palp_scene_release(sScene);
        sScene = nullptr;
    }

    /// Creates a session, steps it 200 ticks and releases it; returns the creation status
    /// (and checks the steps when it was accepted).
    static palp_status createAndStep(const palp_session_params& p, const palp_trajectory& t,
                                     const std::string& what) {
        palp_session* session = nullptr;
        const palp_status st = palp_session_create_simulated(sScene, &p, &t, &session);
        EXPECT_NE(st, PALP_ERROR_INTERNAL) << what << ": " << palp_last_error();
        if (st != PALP_OK) {
            EXPECT_EQ(session, nullptr) << what;
            return st;
        }
        palp_snapshot s;
        EXPECT_EQ(palp_session_step(session, 200, &s), PALP_OK)
            << what << ": " << palp_last_error();
        EXPECT_TRUE(std::isfinite(s.force[0]) && std::isfinite(s.force[1]) &&
                    std::isfinite(s.force[2]))
            << what;
        palp_session_release(session);
        return st;
    }

    static palp_scene* sScene;
};

palp_scene* CApiFields::sScene = nullptr;

/// A session the tests vary one field of: VC (every field still checked) on a press.
palp_session_params defaultParams() {
    palp_session_params p;
    palp_session_params_default(&p);
    p.mode = PALP_MODE_AVC;
    p.source = PALP_SOURCE_VOLUME_FIRST_HIT;
    return p;
}

palp_session_params& defaultParamsRef() {
    static palp_session_params p = defaultParams();
    return p;
}

void expectRefusalNaming(palp_status st, const std::string& field, const std::string& what) {
    EXPECT_EQ(st, PALP_ERROR_INVALID_ARGUMENT) << what;
    EXPECT_NE(std::string(palp_last_error()).find(field), std::string::npos)
        << what << ": the message must name " << field << ": " << palp_last_error();
}

TEST_F(CApiFields, EverySessionParameterRefusesBadNumbersNamingTheField) {
    // What the fields' ranges (palp.h, bounds.h) admit among the bad values.
    const std::set<std::pair<std::string, double>> accepted = {{"damping", 0.0},
                                                               {"threshold", -1.0},
                                                               {"threshold", 0.0},
                                                               {"hardness", 0.0},
                                                               {"static_friction", 0.0},
                                                               {"dynamic_friction", 0.0},
                                                               {"cross_fade_seconds", 0.0},
                                                               {"recontact_seconds", 0.0},
                                                               {"workspace_offset", -1.0},
                                                               {"workspace_offset", 0.0}};
    int refused = 0;
    for (const auto& f : kParamFields) {
        for (int i = 0; i < f.count; ++i) {
            for (double v : kBadValues) {
                palp_session_params p = defaultParams();
                palp_trajectory t;
                ASSERT_EQ(palp_trajectory_default(PALP_TRAJECTORY_PRESS, &t), PALP_OK);
                f.at(p)[i] = v;
                const std::string what =
                    std::string(f.name) + "[" + std::to_string(i) + "] = " + show(v);
                const double before = f.at(defaultParamsRef())[i];
                const palp_status st = createAndStep(p, t, what);
                if (v == before) {  // unchanged (an off-diagonal 0 of the identity rotation)
                    EXPECT_EQ(st, PALP_OK) << what << ": " << palp_last_error();
                    continue;
                }
                // A lower static friction than the default dynamic one is refused, naming the
                // dynamic one; that pair is not what this row tests.
                if (std::string(f.name) == "static_friction" && v == 0.0) {
                    expectRefusalNaming(st, "dynamic_friction", what);
                    continue;
                }
                if (!std::isnan(v) && accepted.count({f.name, v})) {  // NaN breaks set order
                    EXPECT_EQ(st, PALP_OK) << what << ": " << palp_last_error();
                    continue;
                }
                // workspace_rotation: any change of one entry leaves a non-rotation (or a
                // non-finite matrix): refused naming workspace_rotation.
                expectRefusalNaming(st, f.name, what);
                ++refused;
            }
        }
    }
    EXPECT_GT(refused, 100);
}

TEST_F(CApiFields, EveryTrajectoryFieldOfEveryKindRefusesBadNumbersNamingTheField) {
    const palp_trajectory_kind kinds[] = {PALP_TRAJECTORY_PRESS, PALP_TRAJECTORY_SWEEP,
                                          PALP_TRAJECTORY_RASTER, PALP_TRAJECTORY_CIRCLE,
                                          PALP_TRAJECTORY_SINUSOID};
    // Fields a kind uses; the others are ignored by that kind (documented in palp.h).
    auto uses = [](palp_trajectory_kind k, const std::string& f) {
        static const std::set<std::string> hand = {"hand_mass", "hand_stiffness", "hand_damping",
                                                   "centre"};
        if (hand.count(f)) return true;
        switch (k) {
            case PALP_TRAJECTORY_PRESS:
                return f == "direction" || f == "depth" || f == "press_seconds" ||
                       f == "hold_seconds";
            case PALP_TRAJECTORY_SWEEP:
                return f == "direction" || f == "press_direction" || f == "length" ||
                       f == "speed" || f == "depth" || f == "approach" || f == "approach_seconds" ||
                       f == "turn_seconds";
            case PALP_TRAJECTORY_RASTER:
                return f == "u" || f == "v" || f == "press_direction" || f == "extent_u" ||
                       f == "extent_v" || f == "line_spacing" || f == "speed" || f == "depth" ||
                       f == "approach" || f == "approach_seconds";
            case PALP_TRAJECTORY_CIRCLE:
                return f == "u" || f == "v" || f == "press_direction" || f == "radius" ||
                       f == "frequency" || f == "depth" || f == "approach" ||
                       f == "approach_seconds";
            case PALP_TRAJECTORY_SINUSOID:
                return f == "direction" || f == "amplitude" || f == "frequency" ||
                       f == "grow_seconds";
        }
        return false;
    };
    // Values the ranges admit: zero lengths and durations where a path may stand still or skip
    // a phase, a point within 10 m, and a direction vector that is still finite and non-zero.
    auto admits = [](const std::string& f, const double* field, double v) {
        if (f == "centre") return std::isfinite(v) && std::abs(v) <= 10;
        if (f == "direction" || f == "press_direction" || f == "u" || f == "v") {
            const double n =
                std::sqrt(field[0] * field[0] + field[1] * field[1] + field[2] * field[2]);
            return std::isfinite(n) && n > 0;
        }
        static const std::set<std::string> mayBeZero = {
            "depth",     "extent_v",  "hold_seconds", "approach",       "radius",
            "frequency", "amplitude", "grow_seconds", "hand_stiffness", "hand_damping"};
        return v == 0.0 && mayBeZero.count(f) > 0;
    };
    int refused = 0, accepted = 0;
    for (palp_trajectory_kind kind : kinds) {
        for (const auto& f : kTrajectoryFields) {
            if (!uses(kind, f.name)) continue;
            for (int i = 0; i < f.count; ++i) {
                for (double v : kBadValues) {
                    const palp_session_params p = defaultParams();
                    palp_trajectory t;
                    ASSERT_EQ(palp_trajectory_default(kind, &t), PALP_OK);
                    f.at(t)[i] = v;
                    const std::string what = "kind " + std::to_string(kind) + " " + f.name + "[" +
                                             std::to_string(i) + "] = " + show(v);
                    const palp_status st = createAndStep(p, t, what);
                    if (admits(f.name, f.at(t), v)) {
                        EXPECT_EQ(st, PALP_OK) << what << ": " << palp_last_error();
                        ++accepted;
                        continue;
                    }
                    expectRefusalNaming(st, f.name, what);
                    ++refused;
                }
            }
        }
    }
    EXPECT_GT(refused, 150);
    EXPECT_GT(accepted, 10);
}

// A C enum field may hold any int; palp reads it as bytes and refuses it by name (loading it as
// the enum type would be undefined behaviour, which the sanitizer run and the fuzzer catch).
TEST_F(CApiFields, EnumFieldsHoldingAnyIntAreRefusedByName) {
    for (int bad : {-2, 7, 99, 1 << 30}) {  // none is an enumerator of the three
        palp_session_params p = defaultParams();
        palp_trajectory t;
        ASSERT_EQ(palp_trajectory_default(PALP_TRAJECTORY_PRESS, &t), PALP_OK);
        std::memcpy(&p.mode, &bad, sizeof bad);
        expectRefusalNaming(createAndStep(p, t, "mode"), "palp_session_params.mode", "mode");
        p = defaultParams();
        std::memcpy(&p.source, &bad, sizeof bad);
        expectRefusalNaming(createAndStep(p, t, "source"), "palp_session_params.source", "source");
        p = defaultParams();
        std::memcpy(&t.kind, &bad, sizeof bad);
        expectRefusalNaming(createAndStep(p, t, "kind"), "palp_trajectory.kind", "kind");
    }
}

TEST_F(CApiFields, SetParamsOnALiveSessionRefusesBadNumbersAndKeepsTheOldOnes) {
    palp_session_params p = defaultParams();
    palp_trajectory t;
    ASSERT_EQ(palp_trajectory_default(PALP_TRAJECTORY_PRESS, &t), PALP_OK);
    palp_session* session = nullptr;
    ASSERT_EQ(palp_session_create_simulated(sScene, &p, &t, &session), PALP_OK)
        << palp_last_error();
    for (const char* name : {"stiffness", "ray_length", "ray_step", "threshold", "damping"}) {
        for (double v : {std::nan(""), 1e300, -1.0}) {
            palp_session_params q = p;
            for (const auto& f : kParamFields) {
                if (std::string(f.name) == name) *f.at(q) = v;
            }
            if (std::string(name) == "threshold" && v == -1.0) continue;  // a valid HU
            if (std::string(name) == "damping" && v == 0.0) continue;
            const std::string what = std::string(name) + " = " + show(v);
            expectRefusalNaming(palp_session_set_params(session, &q), name, what);
        }
    }
    palp_session_params now;
    ASSERT_EQ(palp_session_get_params(session, &now), PALP_OK);
    EXPECT_EQ(now.stiffness, p.stiffness);
    EXPECT_EQ(now.ray_length, p.ray_length);
    palp_snapshot s;
    EXPECT_EQ(palp_session_step(session, 100, &s), PALP_OK);
    palp_session_release(session);
}

}  // namespace
