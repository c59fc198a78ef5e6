// Deformable scenes through the C API (palp_deformable_options, palp_scene_make_deformable):
// every number and enum field given nan, inf, -inf, -1, 0, 1e300 (or ints out of range) is
// refused naming the field and the value, or accepted and then steps finite (never
// PALP_ERROR_INTERNAL, never an abort); and the C session on a deformable scene renders the
// same forces, tick for tick, as the C++ Session on the same body and path (AVCEC, both
// solvers, offline and deterministic).

#include <gtest/gtest.h>

#include <cmath>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <limits>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "palp/haptics/devices/simulated_device.h"
#include "palp/haptics/scene.h"
#include "palp/haptics/session.h"
#include "palp/haptics/tissue/deformable_setup.h"
#include "palp/haptics/tissue/error_table.h"
#include "palp/palp.h"
#include "palp/volume/phantom.h"
#include "test_support.h"

namespace {

namespace ph = palp::haptics;

constexpr double kVoxel = 2e-3;  // the bone phantom's voxel, m

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

struct DoubleField {
    const char* name;
    double palp_deformable_options::*field;
};

// When a field is added to palp.h, this size changes: add it to the tables below.
static_assert(sizeof(palp_deformable_options) == 160,
              "palp_deformable_options changed: update the table");

#define PALP_DFIELD(f) \
    DoubleField { #f, &palp_deformable_options::f }
const std::vector<DoubleField> kDoubleFields = {
    PALP_DFIELD(element_size),   PALP_DFIELD(tissue_threshold),      PALP_DFIELD(bone_threshold),
    PALP_DFIELD(youngs_modulus), PALP_DFIELD(poisson_ratio),         PALP_DFIELD(density),
    PALP_DFIELD(damping_alpha),  PALP_DFIELD(damping_beta),          PALP_DFIELD(filter_width),
    PALP_DFIELD(period),         PALP_DFIELD(contact_damping_ratio), PALP_DFIELD(secondary_rate)};
#undef PALP_DFIELD

class CApiDeformable : public ::testing::Test {
  protected:
    static void SetUpTestSuite() {
        ASSERT_EQ(palp_volume_make_phantom("bone", 0, nullptr, kVoxel, &sVolume), PALP_OK)
            << palp_last_error();
        double lo[3], hi[3];
        ASSERT_EQ(palp_volume_geometry(sVolume, nullptr, lo, hi), PALP_OK);
        sCentre[0] = 0.5 * (lo[0] + hi[0]);
        sCentre[1] = lo[1] - 5e-3;
        sCentre[2] = 0.5 * (lo[2] + hi[2]);
    }
    static void TearDownTestSuite() {
        palp_volume_release(sVolume);
        sVolume = nullptr;
    }

    /// Makes a scene from @p o; on success steps a VC press 30 ticks and checks it is finite.
    static palp_status tryOptions(const palp_deformable_options& o, const std::string& what) {
        palp_scene* scene = nullptr;
        const palp_status st = palp_scene_make_deformable(sVolume, NAN, &o, &scene);
        EXPECT_NE(st, PALP_ERROR_INTERNAL) << what << ": " << palp_last_error();
        if (st != PALP_OK) {
            EXPECT_EQ(scene, nullptr) << what;
            return st;
        }
        palp_session_params p;
        palp_session_params_default(&p);
        p.mode = PALP_MODE_VC;
        p.period = o.period;
        palp_trajectory t;
        EXPECT_EQ(palp_trajectory_default(PALP_TRAJECTORY_PRESS, &t), PALP_OK);
        std::memcpy(t.centre, sCentre, sizeof t.centre);
        t.direction[0] = 0;
        t.direction[1] = 1;
        t.direction[2] = 0;
        palp_session* session = nullptr;
        EXPECT_EQ(palp_session_create_simulated(scene, &p, &t, &session), PALP_OK)
            << what << ": " << palp_last_error();
        palp_snapshot s{};
        EXPECT_EQ(palp_session_step(session, 30, &s), PALP_OK) << what;
        EXPECT_TRUE(std::isfinite(s.force[0]) && std::isfinite(s.force[1]) &&
                    std::isfinite(s.force[2]))
            << what;
        palp_session_release(session);
        palp_scene_release(scene);
        return st;
    }

    static palp_volume* sVolume;
    static double sCentre[3];
};

palp_volume* CApiDeformable::sVolume = nullptr;
double CApiDeformable::sCentre[3] = {0, 0, 0};

void expectRefused(palp_status st, const std::string& name, const std::string& value,
                   const std::string& what) {
    EXPECT_EQ(st, PALP_ERROR_INVALID_ARGUMENT) << what;
    const std::string m = palp_last_error();
    EXPECT_NE(m.find("palp_deformable_options." + name), std::string::npos) << what << ": " << m;
    EXPECT_NE(m.find(value), std::string::npos) << what << ": " << m;
}

TEST_F(CApiDeformable, EveryNumberFieldRefusesBadValuesNamingTheFieldAndValue) {
    int refused = 0, accepted = 0;
    for (const DoubleField& f : kDoubleFields) {
        for (const double v : kBadValues) {
            palp_deformable_options o;
            palp_deformable_options_default(&o);
            o.*f.field = v;
            const std::string what = std::string(f.name) + " = " + show(v);
            const palp_status st = tryOptions(o, what);
            const bool noneValue = std::string(f.name) == "bone_threshold" &&
                                   (std::isnan(v) || v == std::numeric_limits<double>::infinity());
            if (!std::isfinite(v) && !noneValue) {
                // Never a value for any field (bone_threshold: NAN and INFINITY mean none).
                expectRefused(st, f.name, show(v), what);
            } else if (v == 1e300) {
                expectRefused(st, f.name, "1e+300", what);
            } else if (st != PALP_OK) {
                // In the field's range but not a body (e.g. all tissue bone: nothing free): the
                // library's refusal, said to come from this call.
                const std::string m = palp_last_error();
                EXPECT_TRUE(m.find("palp_deformable_options." + std::string(f.name)) !=
                                std::string::npos ||
                            m.find("palp_scene_make_deformable: ") != std::string::npos)
                    << what << ": " << m;
            }
            (st == PALP_OK ? accepted : refused) += 1;
        }
    }
    EXPECT_GT(refused, 50);
    EXPECT_GT(accepted, 5);  // 0 damping, 0 filter, a -1 HU tissue threshold, ...
}

TEST_F(CApiDeformable, EnumsCountsAndTheCentreAreRefusedByName) {
    const auto set = [](auto&& edit) {
        palp_deformable_options o;
        palp_deformable_options_default(&o);
        edit(o);
        palp_scene* scene = nullptr;
        const palp_status st = palp_scene_make_deformable(CApiDeformable::sVolume, NAN, &o, &scene);
        palp_scene_release(scene);
        return st;
    };
    for (const int v : {-1, 7, 1 << 30}) {
        const palp_status st = set([&](palp_deformable_options& o) {
            std::memcpy(&o.support_face, &v, sizeof v);  // a C enum may hold any int
        });
        expectRefused(st, "support_face", std::to_string(v), "support_face " + std::to_string(v));
    }
    for (const int v : {-1, 3}) {  // 2 is PALP_FEM_AUTO
        const palp_status st =
            set([&](palp_deformable_options& o) { std::memcpy(&o.solver, &v, sizeof v); });
        expectRefused(st, "solver", std::to_string(v), "solver " + std::to_string(v));
    }
    for (const int v : {-1, 2}) {
        const palp_status st =
            set([&](palp_deformable_options& o) { std::memcpy(&o.inside_bone, &v, sizeof v); });
        expectRefused(st, "inside_bone", std::to_string(v), "inside_bone " + std::to_string(v));
    }
    for (const int v : {-1, 3, 8}) {
        const palp_status st = set([&](palp_deformable_options& o) { o.lod = v; });
        expectRefused(st, "lod", std::to_string(v), "lod " + std::to_string(v));
    }
    for (const int v : {0, -5, 1 << 30}) {
        const palp_status st = set([&](palp_deformable_options& o) { o.primary_nodes = v; });
        expectRefused(st, "primary_nodes", std::to_string(v), "primary_nodes " + std::to_string(v));
    }
    for (const double v : {1e300, std::numeric_limits<double>::infinity(), 11.0}) {
        // One coordinate NAN and another not a position: the centre is all NAN or a point.
        const palp_status st = set([&](palp_deformable_options& o) {
            o.regions_centre[0] = NAN;
            o.regions_centre[1] = v;
            o.regions_centre[2] = 0;
        });
        expectRefused(st, "regions_centre[0]", "nan", "regions_centre " + show(v));
    }
    // hard_iso: NAN means none; anything else must be a value.
    palp_deformable_options o;
    palp_deformable_options_default(&o);
    palp_scene* scene = nullptr;
    EXPECT_EQ(palp_scene_make_deformable(sVolume, 1e300, &o, &scene), PALP_ERROR_INVALID_ARGUMENT);
    EXPECT_NE(std::string(palp_last_error()).find("hard_iso"), std::string::npos);
    EXPECT_EQ(palp_scene_make_deformable(nullptr, NAN, &o, &scene), PALP_ERROR_INVALID_ARGUMENT);
    EXPECT_EQ(palp_scene_make_deformable(sVolume, NAN, nullptr, &scene),
              PALP_ERROR_INVALID_ARGUMENT);
    EXPECT_EQ(scene, nullptr);
}

// material_law and material_table through the C API: the law and the table reach the body
// (PALP_FEM_AUTO takes the whole mesh for neo-Hookean tissue and says why; the regions, a law
// out of range and a bad table are refused by name), and the same press as `palp palpate
// --deformable --material neo-hookean` on the same scene feels the CLI's force.
TEST_F(CApiDeformable, TheMaterialLawAndTableReachTheBodyAsTheCliMakesIt) {
    const auto make = [](auto&& edit, palp_scene** scene) {
        palp_deformable_options o;
        palp_deformable_options_default(&o);
        EXPECT_EQ(o.material_law, PALP_MATERIAL_LINEAR);
        EXPECT_EQ(o.material_table, nullptr);
        edit(o);
        return palp_scene_make_deformable(CApiDeformable::sVolume, NAN, &o, scene);
    };
    palp_scene* scene = nullptr;
    for (const int v : {-1, 2}) {
        const palp_status st =
            make([&](palp_deformable_options& o) { std::memcpy(&o.material_law, &v, sizeof v); },
                 &scene);
        expectRefused(st, "material_law", std::to_string(v), "material_law " + std::to_string(v));
    }
    palp::test::TempDir tmp;
    const std::string bad = (tmp / "bad.csv").string();
    {
        std::ofstream(bad) << "name,lo,hi,youngs_pa,poisson,density_kg_m3,source\n"
                              "soft,-200,500,-4000,0.45,1000,ref\n";
    }
    expectRefused(make([&](palp_deformable_options& o) { o.material_table = bad.c_str(); }, &scene),
                  "material_table", bad + " line 2 (row 'soft') youngs_pa", "a bad table");
    EXPECT_EQ(scene, nullptr);
    ASSERT_EQ(make([](palp_deformable_options& o) { o.material_table = "ct"; }, &scene), PALP_OK)
        << palp_last_error();
    palp_scene_release(scene);

    // The press `palp palpate` makes from the CLI's options below, through the C API.
    constexpr double kDepth = 6e-3, kOut = 15e-3, kSpeed = 0.1, kHold = 0.6;
    double force[2] = {0, 0};
    for (const palp_material_law law : {PALP_MATERIAL_LINEAR, PALP_MATERIAL_NEO_HOOKEAN}) {
        ASSERT_EQ(make([&](palp_deformable_options& o) { o.material_law = law; }, &scene), PALP_OK)
            << palp_last_error();
        palp_solver_choice choice{};
        ASSERT_EQ(palp_scene_solver(scene, &choice), PALP_OK);
        EXPECT_EQ(choice.solver, PALP_FEM_WHOLE_MESH);
        EXPECT_EQ(choice.chosen, 1);
        if (law == PALP_MATERIAL_NEO_HOOKEAN) {
            EXPECT_NE(std::string(choice.reason).find("neo-Hookean"), std::string::npos)
                << choice.reason;
        }
        palp_session_params p;
        palp_session_params_default(&p);
        p.mode = PALP_MODE_VC;
        p.stiffness = 600;
        p.max_stiffness = 2400;
        p.damping = 0;
        p.static_friction = 0.5;
        p.dynamic_friction = 0.3;
        p.device = "3D Systems Touch";
        palp_trajectory t;
        ASSERT_EQ(palp_trajectory_default(PALP_TRAJECTORY_PRESS, &t), PALP_OK);
        t.centre[0] = sCentre[0];
        // sCentre is 5 mm out of the active voxels' centres; palp palpate's face is half a
        // voxel further out (the voxels' box) and its press starts 15 mm out of that.
        t.centre[1] = sCentre[1] + 5e-3 - 0.5 * kVoxel - kOut;
        t.centre[2] = sCentre[2];
        t.direction[0] = 0;
        t.direction[1] = 1;
        t.direction[2] = 0;
        t.depth = kDepth + kOut;
        t.press_seconds = (kDepth + kOut) / kSpeed;
        t.hold_seconds = kHold;
        palp_session* session = nullptr;
        ASSERT_EQ(palp_session_create_simulated(scene, &p, &t, &session), PALP_OK)
            << palp_last_error();
        const int ticks = static_cast<int>(std::ceil((t.press_seconds + kHold) / 1e-3));
        double maxForce = 0;
        for (int i = 0; i < ticks; ++i) {
            palp_snapshot snap{};
            ASSERT_EQ(palp_session_step(session, 1, &snap), PALP_OK);
            maxForce = std::max(maxForce, std::hypot(snap.force[0], snap.force[1], snap.force[2]));
        }
        force[law == PALP_MATERIAL_NEO_HOOKEAN ? 1 : 0] = maxForce;
        palp_session_release(session);
        palp_scene_release(scene);
    }
    EXPECT_GT(force[1], force[0]);  // neo-Hookean tissue stiffens as it is pressed
    if (!std::filesystem::exists(palp::test::palpTool()))
        GTEST_SKIP() << "no palp tool (PALP_BUILD_TOOLS off) to compare with";
    const auto r = palp::test::runCommand(
        palp::test::palpTool().string() +
        " palpate --phantom bone --voxel-mm 2 --deformable --material neo-hookean --fast "
        "--trajectory press --hold 0.6 --mode vc --k-base 600 --depth 6 --json");
    ASSERT_EQ(r.exitCode, 0) << r.output;
    const auto j = nlohmann::json::parse(r.output.substr(r.output.find('{')), nullptr, false);
    ASSERT_FALSE(j.is_discarded()) << r.output;
    const double cli = j["max_force_n"];
    std::printf("press 6 mm: C API linear %.4f N, neo-Hookean %.4f N; palp palpate %.4f N\n",
                force[0], force[1], cli);
    EXPECT_NEAR(force[1], cli, 0.02 * cli);
}

// The C session and the C++ Session on the same body (the same volume, options and support),
// the same press and hand, AVCEC from the volume (the C defaults): the same force at every
// tick, bit for bit, with either solver (the regions synchronous: deterministic).
TEST_F(CApiDeformable, CSessionAndCppSessionAgreeTickForTick) {
    for (const palp_fem_solver solver : {PALP_FEM_WHOLE_MESH, PALP_FEM_REGIONS}) {
        SCOPED_TRACE(solver == PALP_FEM_WHOLE_MESH ? "whole mesh" : "regions");
        palp_deformable_options o;
        palp_deformable_options_default(&o);
        o.solver = solver;
        o.threaded = 0;
        o.regions_centre[0] = sCentre[0];
        o.regions_centre[1] = 0;
        o.regions_centre[2] = sCentre[2];
        palp_scene* cScene = nullptr;
        ASSERT_EQ(palp_scene_make_deformable(sVolume, NAN, &o, &cScene), PALP_OK)
            << palp_last_error();
        palp_session_params p;
        palp_session_params_default(&p);  // AVCEC, volume first hit
        palp_trajectory t;
        ASSERT_EQ(palp_trajectory_default(PALP_TRAJECTORY_PRESS, &t), PALP_OK);
        std::memcpy(t.centre, sCentre, sizeof t.centre);
        t.direction[0] = 0;
        t.direction[1] = 1;
        t.direction[2] = 0;
        t.depth = 9e-3;
        t.press_seconds = 0.3;
        t.hold_seconds = 0.2;
        palp_session* cSession = nullptr;
        ASSERT_EQ(palp_session_create_simulated(cScene, &p, &t, &cSession), PALP_OK)
            << palp_last_error();

        // The same through C++: the body from the library's set-up, the C defaults' C++ twins.
        palp::volume::PhantomSpec spec;
        spec.params.scene = palp::volume::PhantomScene::Bone;
        spec.voxelSize = kVoxel;
        const palp::volume::Volume vol = palp::volume::makePhantomVolume(spec);
        ph::DeformableSetup setup;
        setup.supportFace = palp::fem::BoxFace::yMax;
        setup.setPeriod(1e-3);
        setup.options.regions.threaded = false;
        setup.options.regions.primaryNodes = 60;
        setup.options.regions.secondaryRate = 100;
        setup.options.regions.lod = 0;
        if (solver == PALP_FEM_REGIONS) {
            setup.options.solverKind = ph::DeformableSolver::asyncRegions;
            setup.options.regionsCentre = Eigen::Vector3d(sCentre[0], 0, sCentre[2]);
        }
        ph::SceneOptions so;
        so.surfaceIso = NAN;
        auto scene = ph::Scene::fromVolume(vol, so);
        scene->setDeformable(ph::makeDeformableModel(vol, setup));
        ph::PressTrajectory press;
        press.start = Eigen::Vector3d(sCentre[0], sCentre[1], sCentre[2]);
        press.direction = Eigen::Vector3d::UnitY();
        press.depthM = t.depth;
        press.pressSeconds = t.press_seconds;
        press.holdSeconds = t.hold_seconds;
        const ph::DeviceSpec* touchX = ph::findDeviceSpec("3D Systems Touch X");
        ASSERT_NE(touchX, nullptr);
        ph::SimulatedDevice device(*touchX, press, ph::HandModel{}, 1e-3);
        ph::Session session(scene, device, ph::SessionParams{});

        int contact = 0, differ = 0;
        double maxForce = 0;
        for (int i = 0; i < 500; ++i) {
            palp_snapshot c{};
            ASSERT_EQ(palp_session_step(cSession, 1, &c), PALP_OK);
            const ph::Snapshot& s = session.step();
            for (int a = 0; a < 3; ++a) {
                if (c.force[a] != s.force[a] || c.proxy[a] != s.proxy[a]) ++differ;
            }
            contact += c.contact_count > 0 ? 1 : 0;
            maxForce = std::max(maxForce, s.force.norm());
        }
        EXPECT_EQ(differ, 0);
        EXPECT_GT(contact, 200);  // the comparison covers a press, not free space
        EXPECT_GT(maxForce, 0.1);
        palp_session_release(cSession);
        palp_scene_release(cScene);
    }
}

}  // namespace

// inside_bone through the C API, on a volume made from memory: a 2 mm bone box (1000 HU,
// x, z 4..20 mm, y 8..24 mm) full of soft tissue under a soft slab (y 0..8 mm), air around.
// PALP_INSIDE_BONE_KEEP: a solid body, no surface inside the box; _DROP (the default): the
// enclosed tissue goes and the deformable surface reaches into the box.
TEST(CApiDeformableInsideBone, KeepAndDropReachTheBody) {
    constexpr std::int64_t n = 24;
    std::vector<std::int16_t> hu(static_cast<std::size_t>(n * n * n), -1000);
    const auto inBox = [](std::int64_t x, std::int64_t lo, std::int64_t hi) {
        return x >= lo && x < hi;
    };
    for (std::int64_t k = 0; k < n; ++k)
        for (std::int64_t j = 0; j < n; ++j)
            for (std::int64_t i = 0; i < n; ++i) {
                std::int16_t v = -1000;
                if (j < 8) v = 40;
                if (inBox(i, 4, 20) && inBox(k, 4, 20) && inBox(j, 8, 24)) {
                    const bool inner = inBox(i, 6, 18) && inBox(k, 6, 18) && inBox(j, 10, 22);
                    v = inner ? 40 : 1000;
                }
                hu[static_cast<std::size_t>(i + n * (j + n * k))] = v;
            }
    const std::int64_t dims[3] = {n, n, n};
    const double mm[16] = {1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1};
    palp_volume* volume = nullptr;
    ASSERT_EQ(palp_volume_from_memory(hu.data(), PALP_VALUE_I16, dims, nullptr, mm,
                                      PALP_FRAME_LPS_MM, 1e-3, &volume),
              PALP_OK)
        << palp_last_error();
    const auto insideCount = [&](palp_inside_bone mode) {
        palp_deformable_options o;
        palp_deformable_options_default(&o);
        EXPECT_EQ(o.inside_bone, PALP_INSIDE_BONE_DROP);
        o.inside_bone = mode;
        o.element_size = 2e-3;
        o.support_face = PALP_FACE_NONE;  // the bone holds it
        palp_scene* scene = nullptr;
        EXPECT_EQ(palp_scene_make_deformable(volume, NAN, &o, &scene), PALP_OK)
            << palp_last_error();
        if (!scene) return -1;
        size_t nv = 0;
        EXPECT_EQ(palp_scene_surface_size(scene, &nv, nullptr), PALP_OK);
        std::vector<float> rest(3 * nv);
        EXPECT_EQ(palp_scene_surface_topology(scene, nullptr, 0, rest.data(), nv), PALP_OK);
        int inside = 0;  // surface vertices strictly inside the bone box's outer walls
        for (size_t v = 0; v < nv; ++v) {
            const double x = rest[3 * v] * 1e3, y = rest[3 * v + 1] * 1e3,
                         z = rest[3 * v + 2] * 1e3;
            if (x > 5 && x < 19 && y > 9 && y < 23 && z > 5 && z < 19) ++inside;
        }
        palp_scene_release(scene);
        return inside;
    };
    EXPECT_EQ(insideCount(PALP_INSIDE_BONE_KEEP), 0);
    EXPECT_GT(insideCount(PALP_INSIDE_BONE_DROP), 10);
    palp_volume_release(volume);
}

// palp_scene_error_estimate: the built-in error table at the body's material and regions and
// the input given (the worst over an input left NAN); 0 on the whole mesh.
TEST_F(CApiDeformable, ErrorEstimateIsTheTablesForTheBody) {
    auto scene = [&](palp_fem_solver solver, int seeds) {
        palp_deformable_options o;
        palp_deformable_options_default(&o);
        o.solver = solver;
        o.threaded = 0;
        o.primary_nodes = seeds;
        palp_scene* s = nullptr;
        EXPECT_EQ(palp_scene_make_deformable(sVolume, NAN, &o, &s), PALP_OK) << palp_last_error();
        return s;
    };
    palp_scene* regions = scene(PALP_FEM_REGIONS, 60);
    palp_solver_choice choice{};
    ASSERT_EQ(palp_scene_solver(regions, &choice), PALP_OK);
    palp_error_estimate e{};
    ASSERT_EQ(palp_scene_error_estimate(regions, 0.05, 4, &e), PALP_OK) << palp_last_error();
    // The same lookup in C++: the defaults' material (5 kPa, 0.45, 1000 kg/m^3, 60 1/s), the
    // regions' lod, 60 seeds, 100 Hz.
    palp::haptics::ErrorPoint x{};
    using palp::haptics::errorIndex;
    using palp::haptics::ErrorVar;
    x[errorIndex(ErrorVar::youngs)] = 5e3;
    x[errorIndex(ErrorVar::poisson)] = 0.45;
    x[errorIndex(ErrorVar::density)] = 1000;
    x[errorIndex(ErrorVar::damping)] = 60;
    x[errorIndex(ErrorVar::lod)] = choice.lod;
    x[errorIndex(ErrorVar::primary)] = 60;
    x[errorIndex(ErrorVar::rate)] = 100;
    x[errorIndex(ErrorVar::strain)] = 0.05;
    x[errorIndex(ErrorVar::frequency)] = 4;
    const palp::haptics::ErrorEstimate want = palp::haptics::ErrorTable::builtIn().estimate(x);
    EXPECT_DOUBLE_EQ(e.percent, want.percent);
    EXPECT_GT(e.percent, 0);
    EXPECT_EQ(e.in_range, 1);  // damping is no axis of the table: 60 1/s is not flagged
    palp_error_estimate worst{};
    ASSERT_EQ(palp_scene_error_estimate(regions, NAN, NAN, &worst), PALP_OK);
    EXPECT_GE(worst.percent, e.percent);
    palp_scene* few = scene(PALP_FEM_REGIONS, 5);
    palp_error_estimate small{};
    ASSERT_EQ(palp_scene_error_estimate(few, 0.05, 4, &small), PALP_OK);
    EXPECT_GT(small.percent, e.percent);  // a smaller primary, a larger error
    palp_scene* whole = scene(PALP_FEM_WHOLE_MESH, 60);
    ASSERT_EQ(palp_scene_error_estimate(whole, 0.05, 4, &e), PALP_OK);
    EXPECT_EQ(e.percent, 0);
    EXPECT_EQ(palp_scene_error_estimate(regions, -1, 4, &e), PALP_ERROR_INVALID_ARGUMENT);
    EXPECT_NE(std::string(palp_last_error()).find("strain"), std::string::npos);
    EXPECT_EQ(palp_scene_error_estimate(regions, 0.05, 4, nullptr), PALP_ERROR_INVALID_ARGUMENT);
    palp_scene_release(whole);
    palp_scene_release(few);
    palp_scene_release(regions);
}
