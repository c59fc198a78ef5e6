#include "palpate_options.h"

#include <cstdint>
#include <filesystem>
#include <system_error>

#include "option_checks.h"
#include "palp/base/bounds.h"
#include "palp/base/error.h"
#include "palp/base/validate.h"
#include "palp/kernels/ray_bundle.h"
#include "palpate/error_budget.h"

namespace palp::tool {

namespace fs = std::filesystem;

namespace {

/// The input: a file or a phantom scene and its parameters.
void addSceneOptions(CLI::App* app, PalpateArgs& a, CheckedOptions& o) {
    app->add_option("file", a.file, "Volume to palpate (.vdb or any scan palp reads)");
    app->add_option("--phantom", a.phantom, "Built-in scene instead of a file")
        ->check(CLI::IsMember({"avc", "avcec", "bone", "stiffness", "tumour"}));
    o.quadrant = app->add_option("--quadrant", a.quadrant, "avc: quadrant of the hidden box, 0-3")
                     ->check(integerIn(0, 3));
    o.shape =
        app->add_option("--shape", a.shape, "avcec: plate outline")
            ->check(CLI::IsMember({"circle", "triangle", "rectangle", "hexagon", "pentagon"}));
    o.displacement = app->add_option("--displacement", a.displacement, "bone: -1, 0 or 1")
                         ->check(integerIn(-1, 1));
    o.profile = app->add_option("--profile", a.profile, "stiffness: CL transition profile")
                    ->check(CLI::IsMember({"linear", "cosine", "tanh"}));
    o.voxel = app->add_option("--voxel-mm", a.voxelMm, "Phantom voxel edge, mm (default 1)")
                  ->check(within(bounds::kSpacing, kMm));
    o.noise = app->add_option("--noise", a.noiseHu, "Phantom noise standard deviation, HU")
                  ->check(within(bounds::kVolumeSpread, {1, "HU"}));
    o.seed =
        app->add_option("--seed", a.seed, "Phantom noise seed")->check(integerIn(0, INT64_MAX));
}

/// Deformable tissue and its FEM.
void addDeformableOptions(CLI::App* app, PalpateArgs& a, CheckedOptions& o) {
    app->add_flag(
        "--deformable", a.deformable,
        "Deformable tissue: voxelised hexahedral FEM (fixed on the face opposite the press and "
        "inside bone), coupled to the probe implicitly over the surface nodes a Gaussian "
        "filter picks; any --mode");
    o.fem = {
        app->add_option("--fem-cell-mm", a.femCellMm, "deformable: element edge, mm (5)")
            ->check(within(bounds::kSpacing, kMm)),
        app->add_option("--young-kpa", a.youngKpa, "deformable: Young's modulus, kPa (5)")
            ->check(within(bounds::kYoungsModulus, {1e-3, "kPa"})),
        app->add_option("--poisson", a.poisson, "deformable: Poisson's ratio (0.45)")
            ->check(within(bounds::kPoissonRatio)),
        app->add_option("--fem-damping", a.femAlpha,
                        "deformable: mass-proportional damping alpha, 1/s (60)")
            ->check(within(bounds::kMassDamping)),
        app->add_option("--fem-beta", a.femBeta,
                        "deformable: stiffness-proportional damping beta, s (0)")
            ->check(within(bounds::kStiffnessDamping)),
        app->add_option("--recontact-ms", a.recontactMs,
                        "deformable: after the tissue springs back past the probe, the force's "
                        "rise is limited for this long, ms (15; 0 = no limit)")
            ->check(within(bounds::kWindow, {1e3, "ms"})),
        app->add_option("--recontact-rise", a.recontactRiseNps,
                        "deformable: the force's largest rise in that window, N/s (100)")
            ->check(within(bounds::kForceRate)),
        app->add_option("--filter-mm", a.filterMm,
                        "deformable: Gaussian filter width sigma, mm (3; 0 = nearest node)")
            ->check(within(bounds::kSpan, kMm)),
        app->add_option("--bone-hu", a.boneHu,
                        "deformable: cells above this are bone, their nodes fixed (500 HU)")
            ->check(within(bounds::kVolumeValue, {1, "HU"})),
        app->add_option("--tissue-hu", a.tissueHu,
                        "deformable: cells above this are tissue (-200 HU)")
            ->check(within(bounds::kVolumeValue, {1, "HU"})),
        app->add_option("--inside-bone", a.insideBone,
                        "deformable: tissue enclosed by bone (bone on both sides along every "
                        "axis: the brain in a skull), 'drop' (default: the scalp and face on "
                        "the skull) or 'keep' (every cell above --tissue-hu)")
            ->check(CLI::IsMember({"drop", "keep"})),
        app->add_option("--fem-solver", a.femSolver,
                        "deformable: 'auto' (default: the whole mesh where elements x substeps a "
                        "tick is within 8,000, which makes the 1 kHz tick, else the regions; "
                        "the report says which and why), 'explicit' (whole mesh every tick) or "
                        "'regions' (asynchronous regions: explicit primary around the contact, "
                        "implicit secondary; threaded with --realtime, synchronous and "
                        "deterministic with --fast; with --material neo-hookean the primary is "
                        "neo-Hookean and the far field linear)")
            ->check(CLI::IsMember({"auto", "explicit", "regions"})),
        app->add_option("--material", a.material,
                        "deformable: the tissue's law, 'linear' (default: small strain) or "
                        "'neo-hookean' (compressible neo-Hookean at large strain with the same "
                        "small-strain E and nu: TLED on the whole mesh, or in the regions' "
                        "primary; tissue stiffens as it is pressed)")
            ->check(CLI::IsMember({"linear", "neo-hookean"})),
        app->add_option("--material-table", a.materialTable,
                        "deformable: each element's Young's modulus from the scan's value by a "
                        "table (CSV: HU ranges or labels, with E, nu, density and sources; "
                        "docs/algorithms.md 5.2), in place of --young-kpa and --poisson: 'ct' "
                        "(the table palp ships: fat, soft tissue, a stiff lesion class) or a "
                        "file")
            ->check([](const std::string& s) -> std::string {
                if (s == "ct") return {};
                return CLI::ExistingFile(s);
            }),
        app->add_option("--primary-nodes", a.primaryNodes,
                        "regions: seed nodes of the primary region (60)")
            ->check(integerIn(1, 100000)),
        app->add_option("--secondary-hz", a.secondaryHz, "regions: secondary solve rate, Hz (100)")
            ->check(within(bounds::kSolverRate)),
        app->add_option("--lod", a.lod,
                        "regions: secondary level of detail, 1, 2 or 4 (2 where the cell counts "
                        "are even, else 1; 4 where lod 2 would leave the zone a sliding contact "
                        "needs over its cap and 4 divides them: the bone phantom at 2.5 mm)")
            ->check(CLI::IsMember({1, 2, 4}))};
    // Not one of o.fem: accepted anywhere, it acts only on a body on the regions.
    app->add_option("--error-budget", a.errorBudget,
                    "regions: largest contact-force error, percent, the primary size and "
                    "secondary rate are chosen for from palp's error table (default 5.23: the "
                    "stiffness JND for normal pressure); 'off' keeps --primary-nodes and "
                    "--secondary-hz")
        ->check(errorBudgetCheck());
    app->add_option("--error-table", a.errorTable,
                    "regions: the error table --error-budget reads (a file `palp errormap "
                    "--table` wrote; default: the one palp ships)")
        ->check(CLI::ExistingFile);
}

/// Coupling: mode, ray source and its parameters, stiffness, friction, passivity.
void addCouplingOptions(CLI::App* app, PalpateArgs& a) {
    app->add_option("--mode", a.mode, "Coupling: vc, avc or avcec (default per scene)");
    app->add_option("--source", a.source,
                    "Ray source: mesh, first-hit or accumulate (default per scene)");
    app->add_option("--k-base", a.kBase, "Surface stiffness k_s, N/m (default 300)")
        ->check(within(bounds::kPositiveStiffness));
    app->add_option("--k-max", a.kMax,
                    "Stiffness clamp k_max, N/m (default 2400, lowered to the device's limit)")
        ->check(within(bounds::kPositiveStiffness));
    app->add_option("--l-max", a.lMaxMm, "Ray length L_max, mm (default 40)")
        ->check(within(bounds::kLength, kMm));
    app->add_option("--l-ref", a.lRefMm,
                    "L_ref of m(L) = clamp(L_ref / L, 1, m_max), mm (default per scene)")
        ->check(within(bounds::kLength, kMm));
    app->add_option("--m-max", a.mMax, "Largest stiffness multiplier m_max (default 8)")
        ->check(within(bounds::kMultiplier));
    app->add_option("--threshold", a.threshold,
                    "first-hit and mesh: hard-structure value, HU (default per scene)")
        ->check(within(bounds::kVolumeValue, {1, "HU"}));
    app->add_option("--sigma", a.sigmaPerMm,
                    "accumulate: hardness above --sigma-threshold, 1/mm (default 1)")
        ->check(within(bounds::kPositiveHardness, {1e-3, "1/mm"}));
    app->add_option("--sigma-threshold", a.sigmaThreshold,
                    "accumulate: value from which sigma applies, HU (default 500)")
        ->check(within(bounds::kVolumeValue, {1, "HU"}));
    app->add_option(
           "--tau-stop", a.tauStop,
           "accumulate: tau_stop (default 3; 1 on the avcec phantom, whose 2 mm plate gives tau 2)")
        ->check(within(bounds::kTauStop));
    app->add_option("--step", a.stepMm, "Ray sample spacing, mm (default 0.5)")
        ->check(within(bounds::kSpacing, kMm));
    app->add_option("--ring", a.ring, "Low-pass ring rays (default 0)")
        ->check(integerIn(0, kernels::kMaxRingRays));
    app->add_option("--sobel-angle", a.sobelAngle,
                    "AVCEC: spherical stencil spacing delta, rad (default per scene)")
        ->check(within(bounds::kAngle));
    app->add_option("--max-ray-tilt", a.maxRayTilt,
                    "AVCEC: the rays' largest tilt from the contact normal theta_c, rad (default "
                    "0.05; pi/2: none, the rays along the proxy-probe direction)")
        ->check(within(bounds::kRayTilt));
    app->add_option("--surface-offset", a.surfaceOffsetMm,
                    "AVCEC: surface stencil spacing h, mm (default per scene)")
        ->check(within(bounds::kSpacing, kMm));
    app->add_option("--damping", a.damping, "Coupling damping b, N s/m (default 0)")
        ->check(within(bounds::kDamping));
    app->add_option("--surface-iso", a.surfaceIso,
                    "Value of the surface the proxy slides on (default -500 HU; a scan without HU: "
                    "Otsu's threshold of its values)")
        ->check(within(bounds::kVolumeValue, {1, "HU"}));
    app->add_option("--mu-static", a.muStatic, "Static friction (default 0.5)")
        ->check(within(bounds::kFriction));
    app->add_option("--mu-dynamic", a.muDynamic,
                    "Dynamic friction (default 0.3, or --mu-static when lower)")
        ->check(within(bounds::kFriction));
    app->add_flag("--passivity-control", a.passivityControl,
                  "Add the passivity controller (the observer always runs)");
}

/// The scripted path of the simulated hand.
void addPathOptions(CLI::App* app, PalpateArgs& a, CheckedOptions& o) {
    app->add_option("--trajectory", a.trajectory,
                    "Path: raster, sweep, circle or press; or a touch mode of thesis paper III "
                    "over --phantom stiffness (continuous-pressure, discontinuous-pressure, "
                    "lateral-sweep: docs/studies.md)")
        ->check(CLI::IsMember({"raster", "sweep", "circle", "press", "continuous-pressure",
                               "discontinuous-pressure", "lateral-sweep"}));
    app->add_option("--centre", a.centreMm,
                    "Centre x,y,z of the path on the surface, mm (default: the middle of the "
                    "patch of skin facing the press on a scan, else of the volume's lateral box, "
                    "on its face against the press axis; on the skin, the coordinate along the "
                    "press is that face's)")
        ->delimiter(',')
        ->expected(3)
        ->check(within(bounds::kPosition, kMm));
    app->add_option("--extent", a.extentMm,
                    "Raster U,V size (sweep: U is the length), mm (default: the patch of skin "
                    "facing the press on a scan, less 5 mm each side; else the volume's lateral "
                    "box less 5 mm each side)")
        ->delimiter(',')
        ->expected(1, 2)
        ->check(within(bounds::kLength, kMm));
    app->add_option("--spacing", a.spacingMm, "Raster line spacing, mm (default 2)")
        ->check(within(bounds::kSpacing, kMm));
    app->add_option("--speed", a.speedMmps,
                    "Speed along the path, mm/s (default 100 raster, 50 sweep)")
        ->check(within(bounds::kPositiveSpeed, {1e3, "mm/s"}));
    app->add_option("--depth", a.depthMm, "Press depth of the target below the surface, mm")
        ->check(within(bounds::kLength, kMm));
    o.pressAxis = app->add_option(
        "--press-axis", a.pressAxis,
        "Press direction into the body (default +y: anterior to posterior; on a scan whose skin "
        "the path follows, the side of the volume with the most skin facing the press)");
    app->add_option("--follow-skin", a.followSkin,
                    "Lay the path on the skin along the press axis (depth below the skin under "
                    "each point, measured once with the surface's rays): auto (default: on a "
                    "scan, not on a phantom or --deformable), on, or off (a flat plane at the "
                    "volume's face)")
        ->check(CLI::IsMember({"auto", "on", "off"}));
    app->add_option("--sweep-axis", a.sweepAxis,
                    "Sweep direction / raster u axis (default: the first lateral axis)");
    app->add_option("--radius", a.radiusMm, "circle: radius, mm")
        ->check(within(bounds::kLength, kMm));
    app->add_option("--frequency", a.frequencyHz, "circle: revolutions per second")
        ->check(within(bounds::kPositiveFrequency));
    app->add_option("--passes", a.passes, "sweep: passes (direction changes + 1); circle: turns")
        ->check(integerIn(1, 1000));
    app->add_option("--hold", a.holdSeconds, "press: hold time, s")
        ->check(within(bounds::kDuration));
}

}  // namespace

void addServoOptions(CLI::App* app, ServoArgs& servo) {
    app->add_option("--servo-cpu", servo.cpu,
                    "CPU to pin the servo thread to (default -1: the last one the process may "
                    "use)")
        ->check(integerIn(-1, 65535));
    auto* prio = app->add_option("--servo-priority", servo.priority,
                                 "The servo thread's SCHED_FIFO priority 1..99, 0 for none "
                                 "(default 80; a loop that misses more than half its deadlines "
                                 "in two windows of 0.4 s drops it and renders no force, reported)")
                     ->check(integerIn(0, 99));
    app->add_flag("--no-realtime-priority", servo.noRealtimePriority,
                  "Run the servo thread at normal priority (as --servo-priority 0)")
        ->excludes(prio);
    app->add_flag("--mlock", servo.lockMemory,
                  "Lock the process's memory (mlockall of all present and future pages) before "
                  "the servo loop starts, so no tick waits on a page fault (reported; refused "
                  "without CAP_IPC_LOCK or a large enough RLIMIT_MEMLOCK)");
    app->add_flag("--servo-share-cpu", servo.shareCpu,
                  "Let the process's other threads (solver, TBB workers) run on the servo's CPU; "
                  "by default, while the loop runs, their affinity masks lose it (reported as "
                  "'N other threads moved off it')");
}

namespace {

/// How to run, what to write, the device.
void addRunOptions(CLI::App* app, PalpateArgs& a) {
    auto* rt =
        app->add_flag("--realtime", a.realtime, "Run on the 1 kHz servo thread (wall-clock time)");
    auto* fast = app->add_flag("--fast", a.fast, "Step offline as fast as possible (default)");
    rt->excludes(fast);
    app->add_option("--seconds", a.seconds,
                    "Run this long, s: simulated time offline; with --realtime wall-clock "
                    "seconds (an overloaded servo loop that skips ticks still stops on time) "
                    "(default: until the path is done)")
        ->check(within(bounds::kPositiveDuration));
    addServoOptions(app, a.servo);
    app->add_option("--trace", a.trace, "Write a CSV trace of every tick");
    app->add_option("--map", a.map,
                    "Write a map over the palpated plane as a figure with axes in mm, patient "
                    "directions, colour bar and title: .svg (text kept as text), otherwise PNG");
    app->add_option("--map-quantity", a.mapQuantity, "stiffness, force or energy")
        ->check(CLI::IsMember({"stiffness", "force", "energy"}));
    app->add_option("--map-at", a.mapAt,
                    "Bin at the proxy (what the hand feels where it is) or at the centre ray's "
                    "end (where the structure that set k lies)")
        ->check(CLI::IsMember({"proxy", "ray-end"}));
    app->add_option("--map-pixel", a.mapPixelMm, "Map pixel edge, mm (default: --spacing)")
        ->check(within(bounds::kSpacing, kMm));
    app->add_option("--map-underlay", a.mapUnderlay,
                    "Under the map, in grey: the skin's depth below the map's plane along the "
                    "press (skin-depth), the volume's maximum over the rays' reach (L_max) under "
                    "the skin (mip; the whole depth where there is no skin), or none "
                    "(auto: skin-depth on a rigid scan, none on a phantom or --deformable)")
        ->check(CLI::IsMember({"auto", "skin-depth", "mip", "none"}));
    app->add_flag("--grey", a.grey, "Grey map instead of black-red-yellow-white");
    app->add_option("--device", a.device, "Device class whose limits apply");
    app->add_flag("--json", a.json, "Print the figures as JSON");
}

// ---------------------------------------------------------------------------------------------
// Checks before any work

/// A FILE or a phantom, scene options only with their phantom, FEM options only with
/// --deformable. @throw palp::ValueError naming the option.
void checkInputOptions(const PalpateArgs& a, const CheckedOptions& o) {
    if (a.file.empty() == a.phantom.empty()) {
        throw ValueError("palpate: expected a FILE or --phantom SCENE, found " +
                         std::string(a.file.empty() ? "neither" : "both"));
    }
    // Scene options apply to one phantom each; say so instead of ignoring them.
    const struct {
        CLI::Option* option;
        const char* scene;  // nullptr: any phantom
    } sceneOpts[] = {{o.quadrant, "avc"},      {o.shape, "avcec"}, {o.displacement, "bone"},
                     {o.profile, "stiffness"}, {o.voxel, nullptr}, {o.noise, nullptr},
                     {o.seed, nullptr}};
    for (const auto& so : sceneOpts) {
        if (so.option->count() == 0) continue;
        const std::string what = so.scene ? "--phantom " + std::string(so.scene) : "--phantom";
        if (a.phantom.empty()) {
            throw ValueError(so.option->get_name() + ": expected " + what +
                             " (a phantom scene option), found a FILE '" + a.file + "'");
        }
        if (so.scene && a.phantom != so.scene) {
            throw ValueError(so.option->get_name() + ": expected " + what + ", found --phantom " +
                             a.phantom);
        }
    }
    if (!a.deformable) {
        for (CLI::Option* fo : o.fem) {
            if (fo->count() > 0)
                throw ValueError(fo->get_name() +
                                 ": expected --deformable, found a rigid "
                                 "scene");
        }
    }
    if (!a.materialTable.empty()) {
        for (CLI::Option* uniform : {o.youngKpa, o.poisson}) {
            if (uniform->count() > 0)
                throwExpected(uniform->get_name(),
                              "no " + uniform->get_name() + " with --material-table (the table " +
                                  "gives the tissue's moduli and Poisson ratio)",
                              uniform->as<std::string>());
        }
    }
}

/// The device class named by --device. @throw palp::ValueError listing the known ones.
const haptics::DeviceSpec* findDevice(const std::string& name) {
    const haptics::DeviceSpec* spec = haptics::findDeviceSpec(name);
    if (!spec) {
        std::string names;
        for (const auto& s : haptics::deviceSpecs())
            names += (names.empty() ? "'" : ", '") + std::string(s.name) + "'";
        throw ValueError("--device: expected one of " + names + ", found '" + name + "'");
    }
    return spec;
}

/// Output directories exist; depth, spacing and time are usable.
void checkRunOptions(const PalpateArgs& a) {
    for (const std::string* out : {&a.trace, &a.map}) {
        if (out->empty()) continue;
        const fs::path path(*out);
        const fs::path dir = path.has_parent_path() ? path.parent_path() : fs::path(".");
        std::error_code ec;
        if (!fs::is_directory(dir, ec)) {
            throw IoError(path.string() + ": expected an existing directory '" + dir.string() +
                          "' for the output, found none");
        }
    }
    if (a.mapUnderlay != "auto" && a.map.empty()) {
        throw ValueError("--map-underlay " + a.mapUnderlay +
                         ": expected --map FILE to draw it under, found none");
    }
    requirePositive("--depth", a.depthMm, "mm");
    requirePositive("--spacing", a.spacingMm, "mm");
    requireNonNegative("--seconds", a.seconds, "s");
}

}  // namespace

void addPalpateOptions(CLI::App* app, PalpateArgs& args, CheckedOptions& checked) {
    addSceneOptions(app, args, checked);
    addDeformableOptions(app, args, checked);
    addCouplingOptions(app, args);
    addPathOptions(app, args, checked);
    addRunOptions(app, args);
    checked.surfaceIso = app->get_option("--surface-iso");
    checked.tissueHu = app->get_option("--tissue-hu");
    checked.boneHu = app->get_option("--bone-hu");
    checked.threshold = app->get_option("--threshold");
    checked.youngKpa = app->get_option("--young-kpa");
    checked.poisson = app->get_option("--poisson");
}

const haptics::DeviceSpec* checkPalpateOptions(const PalpateArgs& args,
                                               const CheckedOptions& checked) {
    checkInputOptions(args, checked);
    const haptics::DeviceSpec* spec = findDevice(args.device);
    checkRunOptions(args);
    return spec;
}

}  // namespace palp::tool
