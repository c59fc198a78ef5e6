#include "palpate_setup.h"

#include <openvdb/tools/ValueTransformer.h>
#include <sys/resource.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <filesystem>
#include <limits>
#include <nlohmann/json.hpp>
#include <numbers>

#include "commands.h"
#include "palp/base/error.h"
#include "palp/base/validate.h"
#include "palp/haptics/rendering/coupling_defaults.h"
#include "palp/haptics/tissue/deformable_setup.h"
#include "palp/studies/offline_run.h"
#include "palp/studies/touch_modes.h"
#include "palp/volume/load.h"
#include "palpate/error_budget.h"

namespace palp::tool {

namespace fs = std::filesystem;

namespace {

haptics::CouplingMode parseMode(const std::string& s) {
    if (s == "vc") return haptics::CouplingMode::VC;
    if (s == "avc") return haptics::CouplingMode::AVC;
    if (s == "avcec") return haptics::CouplingMode::AVCEC;
    throw ValueError("--mode: expected vc, avc or avcec, found '" + s + "'");
}

haptics::RaySource parseSource(const std::string& s) {
    if (s == "mesh") return haptics::RaySource::Mesh;
    if (s == "first-hit") return haptics::RaySource::VolumeFirstHit;
    if (s == "accumulate") return haptics::RaySource::VolumeAccumulate;
    throw ValueError("--source: expected mesh, first-hit or accumulate, found '" + s + "'");
}

}  // namespace

std::string axisName(const Eigen::Vector3d& a) {
    const int i = axisIndex(a);
    return std::string(a[i] < 0 ? "-" : "+") + "xyz"[i];
}

Input loadInput(const PalpateArgs& a) {
    Input in;
    if (!a.phantom.empty()) {
        requirePositive("--voxel-mm", a.voxelMm, "mm");
        volume::PhantomSpec ps;
        ps.params.scene = volume::parseScene(a.phantom);
        ps.params.quadrant = a.quadrant;
        ps.params.shape = volume::parseShape(a.shape);
        ps.params.displacement = a.displacement;
        ps.params.profile = volume::parseProfile(a.profile);
        ps.voxelSize = a.voxelMm * 1e-3;
        ps.noiseSigmaHu = a.noiseHu;
        ps.seed = a.seed;
        in.vol = volume::makePhantomVolume(ps);
        in.cp = haptics::sceneCouplingDefaults(ps.params.scene);
        in.label = volume::Phantom(ps.params).description();
        in.phantom = ps.params;
    } else {
        in.vol = volume::load({fs::path(a.file)});
        in.cp = haptics::scanCouplingDefaults();
        in.label = a.file;
    }
    return in;
}

haptics::CouplingParams couplingFromOptions(const PalpateArgs& a, haptics::CouplingParams cp) {
    if (!a.mode.empty()) cp.mode = parseMode(a.mode);
    // The deformable tumour: the rays look for the inclusion's embedded surface, which moves
    // with the tissue (the scan's values stay where the undeformed inclusion was).
    if (a.deformable && a.phantom == "tumour") cp.source = haptics::RaySource::Mesh;
    if (!a.source.empty()) cp.source = parseSource(a.source);
    if (std::isfinite(a.kBase)) cp.baseStiffness = a.kBase;
    if (std::isfinite(a.kMax)) {
        if (std::isfinite(a.kBase) && a.kMax < a.kBase) {
            throwExpected("--k-max", "a clamp >= --k-base (" + formatValue(a.kBase) + " N/m)",
                          formatValue(a.kMax) + " N/m");
        }
        cp.maxStiffness = a.kMax;
        // The default surface stiffness follows a clamp set below it.
        if (!std::isfinite(a.kBase)) cp.baseStiffness = std::min(cp.baseStiffness, a.kMax);
    } else if (cp.maxStiffness < cp.baseStiffness) {
        // The default clamp is below the surface stiffness asked for: the clamp follows it (the
        // device's limit then lowers both, and the report says so).
        cp.maxStiffness = cp.baseStiffness;
    }
    if (std::isfinite(a.lMaxMm)) cp.bundle.length = a.lMaxMm * 1e-3;
    if (std::isfinite(a.lRefMm)) cp.referenceLength = a.lRefMm * 1e-3;
    if (std::isfinite(a.mMax)) cp.maxMultiplier = a.mMax;
    if (std::isfinite(a.threshold)) cp.firstHit.threshold = static_cast<float>(a.threshold);
    if (std::isfinite(a.sigmaPerMm) || std::isfinite(a.sigmaThreshold)) {
        const double s = std::isfinite(a.sigmaPerMm) ? a.sigmaPerMm : 1.0;
        const double t = std::isfinite(a.sigmaThreshold) ? a.sigmaThreshold : 500.0;
        requirePositive("--sigma", s, "1/mm");
        cp.accumulate.sigma =
            kernels::TransferFunction::step(static_cast<float>(t), static_cast<float>(s * 1e3));
    }
    if (std::isfinite(a.tauStop)) cp.accumulate.tauStop = a.tauStop;
    if (std::isfinite(a.stepMm)) {
        cp.firstHit.step = a.stepMm * 1e-3;
        cp.accumulate.step = a.stepMm * 1e-3;
    }
    if (a.ring >= 0) cp.bundle.ringCount = a.ring;
    if (std::isfinite(a.sobelAngle)) cp.bundle.sobelAngle = a.sobelAngle;
    if (std::isfinite(a.surfaceOffsetMm)) cp.bundle.surfaceOffset = a.surfaceOffsetMm * 1e-3;
    if (std::isfinite(a.maxRayTilt)) cp.maxRayTilt = a.maxRayTilt;
    if (std::isfinite(a.damping)) cp.damping = a.damping;
    return cp;
}

std::shared_ptr<const haptics::MaterialTable> materialTableFromOptions(const PalpateArgs& a) {
    if (a.materialTable.empty()) return nullptr;
    try {
        return haptics::MaterialTable::named(a.materialTable);
    } catch (const Error& e) {
        throw ValueError("--material-table " + a.materialTable + ": " + e.what());
    }
}

/// What --json says of --material-table: the table, its rows and the body's nu and density.
double peakRssMiB() {
    rusage u{};
    getrusage(RUSAGE_SELF, &u);
    return static_cast<double>(u.ru_maxrss) / 1024.0;  // KiB on Linux
}

long pieceCells(const std::vector<fem::BodyPiece>& pieces) {
    long cells = 0;
    for (const fem::BodyPiece& p : pieces) cells += p.cells;
    return cells;
}

int activeNodes(const fem::HexMesh& mesh) {
    return static_cast<int>(std::count(mesh.nodeActive().begin(), mesh.nodeActive().end(), 1));
}

nlohmann::json materialTableJson(const PalpateArgs& a) {
    const auto table = materialTableFromOptions(a);
    if (!table) return "none";
    nlohmann::json rows = nlohmann::json::array();
    for (const haptics::MaterialRow& row : table->rows())
        rows.push_back({{"name", row.name},
                        {"lo", row.lo},
                        {"hi", row.hi},
                        {"youngs_kpa", row.youngsModulus * 1e-3}});
    return {{"table", table->origin()},
            {"kind", table->kind() == haptics::MaterialTableKind::labels ? "labels" : "ranges"},
            {"poisson", table->poissonRatio()},
            {"density_kg_m3", table->density()},
            {"rows", rows}};
}

std::shared_ptr<const haptics::DeformableModel> makeBody(const PalpateArgs& a, const Input& in,
                                                         const Eigen::Vector3d& press,
                                                         const Eigen::Vector3d& pathCentre,
                                                         double period,
                                                         haptics::SolverChoice* choice,
                                                         const haptics::SlidePatch* slide) {
    requirePositive("--fem-cell-mm", a.femCellMm, "mm");
    requirePositive("--young-kpa", a.youngKpa, "kPa");
    haptics::DeformableSetup setup;  // the library's set-up, shared with the C API
    setup.voxelize.elementSize = a.femCellMm * 1e-3;
    setup.voxelize.tissueThreshold = a.tissueHu;
    setup.voxelize.boneThreshold = a.boneHu;
    setup.voxelize.insideBone =
        a.insideBone == "keep" ? fem::InsideBone::keep : fem::InsideBone::drop;
    setup.material.youngsModulus = a.youngKpa * 1e3;
    setup.material.poissonRatio = a.poisson;
    setup.material.dampingAlpha = a.femAlpha;
    setup.material.dampingBeta = a.femBeta;
    setup.material.law =
        a.material == "neo-hookean" ? fem::MaterialLaw::neoHookean : fem::MaterialLaw::linear;
    setup.materialTable = materialTableFromOptions(a);
    setup.supportFace = haptics::faceOpposite(press);  // the face opposite the pressed one
    setup.options.filterWidth = a.filterMm * 1e-3;
    setup.setPeriod(period);
    setup.autoSolver = a.femSolver == "auto";
    if (a.femSolver != "explicit") {  // the regions' options, used where they are chosen
        if (a.femSolver == "regions")
            setup.options.solverKind = haptics::DeformableSolver::asyncRegions;
        setup.options.regions.primaryNodes = a.primaryNodes;
        setup.options.regions.secondaryRate = a.secondaryHz;
        setup.options.regions.lod = a.lod;  // 0: haptics::autoRegionsLod
        // Offline runs are deterministic (secondary inline every period); a live
        // session solves it on its own thread.
        setup.options.regions.threaded = a.realtime;
        // The regions start under the path, on the pressed face: that face is the one the
        // contact slides on without a factorisation (AsyncRegionsOptions::slideNodes).
        setup.options.regionsCentre = pathCentre;
        // On a scan's curved skin, the skin under the path is what the contact slides over.
        if (slide) setup.slidePatch = *slide;
    }
    const bool tumour = in.phantom && in.phantom->scene == volume::PhantomScene::Tumour;
    if (tumour && !setup.materialTable) {  // a table gives the inclusion its own modulus
        // The inclusion is stiffer tissue (8x, between the soft tissue's HU and its own),
        // free to move: its surface is embedded in the elements and deforms with them.
        const double e = setup.material.youngsModulus;
        const double split =
            0.5 * (in.phantom->materials.softHu + in.phantom->materials.inclusionHu);
        setup.voxelize.youngsFromValue = [e, split](double hu) { return hu > split ? 8 * e : e; };
    }
    auto model = haptics::makeDeformableModel(in.vol, setup, choice);
    model = applyErrorBudget(a, std::move(model));  // --error-budget: primary size and rate
    if (tumour) model->embedMesh(volume::Phantom(*in.phantom).inclusionMesh());
    return model;
}

ScanDefaults scanDefaults(const volume::Volume& vol) {
    ScanDefaults d;
    if (vol.info.modality == "CT" || !vol.grid) return d;
    const openvdb::math::MinMax<float> range = openvdb::tools::minMax(vol.grid->tree());
    const double lo = range.min(), hi = range.max();
    if (!(lo >= -100.0) || !(hi > lo)) return d;
    std::array<double, 256> hist{};
    const double scale = 255.0 / (hi - lo);
    double count = 0;
    for (auto it = vol.grid->cbeginValueOn(); it; ++it) {
        const double weight = static_cast<double>(it.getVoxelCount());
        hist[static_cast<std::size_t>(std::clamp((*it - lo) * scale, 0.0, 255.0))] += weight;
        count += weight;
    }
    // Otsu: the split that maximises the between-class variance.
    double total = 0;
    for (std::size_t b = 0; b < hist.size(); ++b) total += static_cast<double>(b) * hist[b];
    double below = 0, belowSum = 0, best = -1;
    std::size_t split = 0;
    for (std::size_t b = 0; b + 1 < hist.size(); ++b) {
        below += hist[b];
        belowSum += static_cast<double>(b) * hist[b];
        const double above = count - below;
        if (below <= 0 || above <= 0) continue;
        const double m0 = belowSum / below, m1 = (total - belowSum) / above;
        const double between = below * above * (m0 - m1) * (m0 - m1);
        if (between > best) {
            best = between;
            split = b;
        }
    }
    d.applies = true;
    d.threshold = lo + (static_cast<double>(split) + 1.0) / scale;
    d.greatest = hi;
    return d;
}

Eigen::AlignedBox3d volumeBox(const volume::Volume& vol, const std::string& label) {
    const openvdb::BBoxd box = vol.worldBounds();
    if (box.empty()) throw ValueError(label + ": expected a volume with active voxels, found none");
    const double half = 0.5 * vol.voxelSize();
    return {Eigen::Vector3d(box.min().x() - half, box.min().y() - half, box.min().z() - half),
            Eigen::Vector3d(box.max().x() + half, box.max().y() + half, box.max().z() + half)};
}

bool followsSkin(const PalpateArgs& a, const Input& in) {
    // A phantom's skin is the flat face of its box: its path stays as it was. A deformable
    // scan's path follows its skin at rest as a rigid scan's does.
    return a.followSkin == "auto" ? !in.phantom : a.followSkin == "on";
}

SkinPlan planSkin(const PalpateArgs& a, bool pressAxisGiven, const Input& in,
                  const kernels::EmbreeScene& surfaces, const Eigen::AlignedBox3d& box) {
    SkinPlan plan;
    plan.press = parseAxis(pressAxisGiven ? a.pressAxis : "+y", "--press-axis");
    plan.follow = followsSkin(a, in);
    if (!plan.follow) return plan;
    // A phantom's rectangle stays its box's; so does the user's.
    if (in.phantom || (!a.centreMm.empty() && !a.extentMm.empty())) return plan;
    if (pressAxisGiven) {
        plan.patch = haptics::findSkinPatch(surfaces, box, plan.press);
    } else {
        // The sides across S/I: an axial scan's S/I ends cut through the body (flat tissue, not
        // skin; the head CT's inferior end is its broadest flat face).
        plan.patch = haptics::findBestSkinPatch(surfaces, box, {}, haptics::kSidePressAxes);
        plan.press = plan.patch->press;
        plan.pressChosen = true;
    }
    if (!(plan.patch->extentU > 0 && plan.patch->extentV > 0)) {
        throw ValueError(
            std::string(pressAxisGiven ? "--press-axis " + a.pressAxis : "--follow-skin") +
            ": expected skin facing the press (within 35 degrees) over a rectangle "
            "of " +
            in.label + " more than 10 mm across, found none" +
            (pressAxisGiven ? " on that side" : " on any side") +
            " (give --centre and --extent, or --follow-skin off)");
    }
    return plan;
}

PathFrame pathFrame(const PalpateArgs& a, const Eigen::AlignedBox3d& box,
                    const Eigen::Vector3d& press, const haptics::SkinPatch* patch) {
    const int pa = axisIndex(press);
    const Eigen::Vector3d lo = box.min(), hi = box.max();
    Eigen::Vector3d centre = 0.5 * (lo + hi);
    centre[pa] = press[pa] > 0 ? lo[pa] : hi[pa];
    if (patch) centre = patch->centre;
    if (!a.centreMm.empty()) {
        centre = 1e-3 * Eigen::Vector3d(a.centreMm[0], a.centreMm[1], a.centreMm[2]);
    }
    const int ua = (pa + 1) % 3, va = (pa + 2) % 3;
    Eigen::Vector3d u = Eigen::Vector3d::Unit(std::min(ua, va));
    Eigen::Vector3d v = Eigen::Vector3d::Unit(std::max(ua, va));
    double extentU = (hi - lo).dot(u.cwiseAbs()) - 10e-3;
    double extentV = (hi - lo).dot(v.cwiseAbs()) - 10e-3;
    if (patch) {
        // The patch's axes are these (the smaller and the larger index across the press).
        extentU = patch->extentU;
        extentV = patch->extentV;
    }
    if (!a.sweepAxis.empty()) {
        const Eigen::Vector3d su = parseAxis(a.sweepAxis, "--sweep-axis");
        if (axisIndex(su) == pa)
            throw ValueError("--sweep-axis: expected an axis across --press-axis " +
                             axisName(press) + ", found '" + a.sweepAxis + "'");
        if (axisIndex(su) != axisIndex(u)) std::swap(extentU, extentV);
        u = su;
        v = Eigen::Vector3d::Unit(3 - pa - axisIndex(u));
    }
    if (!a.extentMm.empty()) {
        extentU = a.extentMm[0] * 1e-3;
        extentV = (a.extentMm.size() > 1 ? a.extentMm[1] : a.extentMm[0]) * 1e-3;
    }
    requirePositive("--extent (U)", extentU * 1e3, "mm");
    requirePositive("--extent (V)", extentV * 1e3, "mm");
    return {centre, u, v, extentU, extentV};
}

void measureSkin(const PalpateArgs& a, const kernels::EmbreeScene& surfaces,
                 const Eigen::AlignedBox3d& box, PathFrame& f, SkinPlan& plan) {
    if (!plan.follow) return;
    const Eigen::Vector3d& press = plan.press;
    const int pa = axisIndex(press);
    // The heights are measured from the face of the volume against the press, so the path's
    // depth comes from the skin alone.
    f.centre[pa] = press[pa] > 0 ? box.min()[pa] : box.max()[pa];
    haptics::SkinFieldSpec s;
    s.centre = f.centre;
    s.u = f.u.cwiseAbs();
    s.v = f.v.cwiseAbs();
    s.press = press;
    // Room for what leaves the rectangle: the raster's half turns, the circle, the smoothing.
    const double spacing = a.spacingMm * 1e-3;
    const double reach = a.trajectory == "circle" ? 2 * a.radiusMm * 1e-3 : 0.0;
    s.extentU = std::max(f.extentU, reach) + 2 * spacing + 8e-3;
    s.extentV = std::max(f.extentV, reach) + 2 * spacing + 8e-3;
    s.cellM = std::max({1e-3, std::max(s.extentU, s.extentV) / 4000});
    s.startOffsetM = 5e-3;
    s.rayLengthM = box.sizes()[pa] + 10e-3;
    s.smoothM = 2e-3;
    s.maxSlope = 1.0;
    try {
        plan.field =
            std::make_shared<const haptics::SkinField>(haptics::SkinField::measure(surfaces, s));
    } catch (const ValueError& e) {
        throw ValueError("--follow-skin: " + std::string(e.what()) +
                         " (move the path with --centre or --press-axis, or --follow-skin off)");
    }
}

PathPlan trajectoryFromOptions(const PalpateArgs& a, const PathFrame& f,
                               const Eigen::Vector3d& press,
                               const std::shared_ptr<const haptics::SkinField>& skin) {
    const double depth = a.depthMm * 1e-3;
    haptics::Trajectory traj;
    double duration = 0, approach = 0, pressedFrom = 0;
    const std::string& tk = a.trajectory;
    double speed = a.speedMmps;
    if (!std::isfinite(speed)) speed = tk == "sweep" ? 50 : 100;
    requirePositive("--speed", speed, "mm/s");
    if (haptics::isTouchModeName(tk)) {
        // Paper III's touch modes run over the stiffness phantom's boxes, in its frame.
        if (a.phantom != "stiffness")
            throw ValueError(
                "--trajectory " + tk +
                ": expected --phantom stiffness (the touch "
                "modes run over its DP, CP and CL boxes), found " +
                (a.phantom.empty() ? std::string("a FILE") : "--phantom " + a.phantom));
        const haptics::TouchMode mode = haptics::parseTouchMode("--trajectory", tk);
        haptics::TouchParams tp;
        tp.depthM = depth;
        if (std::isfinite(a.speedMmps)) tp.speedMps = a.speedMmps * 1e-3;
        tp.holdSeconds = a.holdSeconds;
        const haptics::TouchPath path = haptics::touchPath(mode, tp);
        return {path.trajectory, path.seconds, path.pressedFrom, path.pressedFrom};
    }
    if (tk == "raster") {
        haptics::RasterTrajectory r;
        r.centre = f.centre;
        r.u = f.u;
        r.v = f.v;
        r.pressDirection = press;
        r.extentU = f.extentU;
        r.extentV = f.extentV;
        r.lineSpacingM = a.spacingMm * 1e-3;
        r.speedMps = speed * 1e-3;
        r.depthM = depth;
        r.skin = skin;
        traj = r;
        duration = haptics::trajectoryDuration(traj) + 0.2;
        pressedFrom = r.approachSeconds;
    } else if (tk == "sweep") {
        haptics::SweepTrajectory s;
        s.centre = f.centre;
        s.direction = f.u;
        s.pressDirection = press;
        s.lengthM = f.extentU;
        s.speedMps = speed * 1e-3;
        s.depthM = depth;
        s.skin = skin;
        traj = s;
        duration = haptics::trajectoryDuration(traj, a.passes);
        approach = pressedFrom = s.approachSeconds;
    } else if (tk == "circle") {
        requirePositive("--radius", a.radiusMm, "mm");
        requirePositive("--frequency", a.frequencyHz, "Hz");
        haptics::CircleTrajectory c;
        c.centre = f.centre;
        c.u = f.u;
        c.v = f.v;
        c.pressDirection = press;
        c.radiusM = a.radiusMm * 1e-3;
        c.frequencyHz = a.frequencyHz;
        c.depthM = depth;
        c.skin = skin;
        traj = c;
        duration = haptics::trajectoryDuration(traj, a.passes);
        approach = c.approachSeconds + c.rampSeconds;
        pressedFrom = c.approachSeconds;
    } else {
        // The hand starts outside the surface, far enough that the session's start-up gate
        // (50 quiet ticks) has opened before it meets the skin: 5 mm, or 0.15 s at its speed
        // when that is longer. From 5 mm at 100 mm/s it met the skin 45 ms in, the gate never
        // opened under the force it then felt, and a press on the head CT rendered nothing.
        const double out = std::max(5e-3, 0.15 * speed * 1e-3);
        haptics::PressTrajectory p;
        p.direction = press;
        p.start = f.centre - out * press;
        p.depthM = depth + out;
        p.pressSeconds = (depth + out) / (speed * 1e-3);
        // When the target reaches the surface on the press's cosine profile.
        approach = pressedFrom =
            p.pressSeconds * std::acos(1 - 2 * out / (depth + out)) / std::numbers::pi;
        p.holdSeconds = a.holdSeconds;
        p.skin = skin;
        traj = p;
        duration = haptics::trajectoryDuration(traj);
    }
    return {traj, duration, approach, pressedFrom};
}

}  // namespace palp::tool
