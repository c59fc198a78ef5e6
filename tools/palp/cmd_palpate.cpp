// palp palpate: palpate a scan or a thesis phantom with VC/AVC/AVCEC along a scripted path
// (simulated hand and device), offline as fast as possible or on the real-time servo loop;
// writes a CSV trace and a PNG map over the palpated plane.

#include <algorithm>
#include <cctype>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <limits>
#include <memory>
#include <nlohmann/json.hpp>
#include <optional>
#include <span>
#include <string>
#include <thread>
#include <vector>

#include "batch_heap.h"
#include "commands.h"
#include "palp/base/bounds.h"
#include "palp/base/error.h"
#include "palp/base/validate.h"
#include "palp/haptics/devices/simulated_device.h"
#include "palp/haptics/devices/trajectory.h"
#include "palp/haptics/rendering/coupling_defaults.h"
#include "palp/haptics/session.h"
#include "palp/studies/energy_budget.h"
#include "palp/studies/map_figure.h"
#include "palp/studies/map_svg.h"
#include "palp/studies/map_underlay.h"
#include "palp/studies/offline_run.h"
#include "palp/studies/scalar_map.h"
#include "palp/studies/trace_csv.h"
#include "palp/volume/load.h"
#include "palp/volume/phantom.h"
#include "palpate/error_budget.h"
#include "palpate_felt.h"
#include "palpate_options.h"
#include "palpate_run.h"
#include "palpate_setup.h"
#include "progress.h"

namespace palp::tool {

namespace fs = std::filesystem;
using nlohmann::json;

namespace {

// ---------------------------------------------------------------------------------------------
// Outputs

/// The map's image right: the path's u, mirrored when the press comes from behind the image
/// (e.g. from P), so that the map is seen from the side the hand presses from (image right x
/// image up points back at the examiner).
Eigen::Vector3d mapRight(const PathFrame& f, const Eigen::Vector3d& press) {
    return f.u.cross(f.v).dot(press) > 0 ? Eigen::Vector3d(-f.u) : f.u;
}

/// The plane --map bins over, image right = mapRight(). @throw palp::ValueError naming
/// --map-pixel when the map would exceed 4096 pixels a side.
haptics::MapPlane mapPlane(const PalpateArgs& a, const PathFrame& f, const Eigen::Vector3d& press) {
    haptics::MapPlane plane;
    plane.centre = f.centre;
    plane.u = mapRight(f, press);
    plane.v = f.v;
    plane.extentU = f.extentU;
    plane.extentV = f.extentV;
    plane.pixelM = (a.mapPixelMm > 0 ? a.mapPixelMm : a.spacingMm) * 1e-3;
    const double side = std::max(plane.extentU, plane.extentV);
    if (side / plane.pixelM > 4096) {
        throwExpected(a.mapPixelMm > 0 ? "--map-pixel" : "--map-pixel (default --spacing)",
                      "at least " + formatValue(side / 4096 * 1e3) + " mm for a " +
                          formatValue(side * 1e3) + " mm map (4096 pixels a side)",
                      formatValue(plane.pixelM * 1e3) + " mm");
    }
    return plane;
}

/// The underlay --map-underlay asks for, computed before the run (off the servo thread) over
/// the map's rectangle in pixels of a quarter of the map's (down to 0.5 mm, or the voxel),
/// measured from the plane of the volume's face against the press; auto: the skin depth on a
/// rigid scan, none on a phantom (its skin is flat) or on deformable tissue (no iso-surface).
/// mip: the volume's maximum over the slab the rays reach (@p reachM) under the skin, or through
/// the whole volume where there is no skin surface. @throw palp::ValueError naming
/// --map-underlay when nothing lies under the map.
std::optional<haptics::MapUnderlay> mapUnderlay(const PalpateArgs& a, const Input& in,
                                                const haptics::Scene& scene,
                                                const haptics::MapPlane& mapPlane,
                                                const Eigen::Vector3d& press,
                                                const Eigen::AlignedBox3d& box, double reachM) {
    std::string kind = a.mapUnderlay;
    if (kind == "auto") kind = in.phantom || a.deformable ? "none" : "skin-depth";
    if (a.map.empty() || kind == "none") return std::nullopt;
    const int pa = axisIndex(press);
    haptics::MapPlane plane = mapPlane;
    plane.centre[pa] = press[pa] > 0 ? box.min()[pa] : box.max()[pa];
    const int cols = plane.cols(), rows = plane.rows();
    const double fine = std::max(0.5e-3, in.vol.voxelSize());
    const int n = std::clamp(static_cast<int>(std::floor(plane.pixelM / fine)), 1,
                             std::clamp(1024 / std::max(cols, rows), 1, 4));
    plane.extentU = cols * plane.pixelM;
    plane.extentV = rows * plane.pixelM;
    plane.pixelM /= n;
    const double length = box.sizes()[pa] + 10e-3;
    haptics::MapUnderlay u(plane);
    const haptics::ScalarMap skin = haptics::skinDepthMap(scene.surfaces(), plane, press, length);
    const bool hasSkin = !skin.finiteValues().empty();
    if (kind == "skin-depth") {
        u.map = skin;
        u.quantity = "skin depth";
        u.units = "mm";
        u.brightLow = true;  // near skin bright, deep skin dark
    } else {
        u.map = haptics::mipMap(in.vol, plane, press, hasSkin ? reachM : length,
                                hasSkin ? &skin : nullptr);
        u.quantity = hasSkin ? "max within " + formatValue(reachM * 1e3) + " mm under the skin"
                             : "max along " + axisName(press);
        u.units = in.vol.info.valueUnits.empty() ? "value" : in.vol.info.valueUnits;
    }
    if (u.map.finiteValues().empty()) {
        throwExpected("--map-underlay " + kind,
                      kind == "skin-depth"
                          ? "a skin surface under the map along " + axisName(press) +
                                " (a deformable scene has none: use mip)"
                          : "the volume under the map along " + axisName(press),
                      "none");
    }
    return u;
}

/// Writes --trace and --map (the map's value range in @p mapLo, @p mapHi, where the map lies in
/// its figure in @p layout; @p kMax: the device's stiffness limit, named on the colour bar when
/// the map reaches it). The map is made
/// before either file is written, and a trace is removed again when the map cannot be written,
/// so a refusal leaves no output behind.
void writeOutputs(const PalpateArgs& a, const PathFrame& f, const Eigen::Vector3d& press,
                  const std::vector<haptics::Snapshot>& snaps, const std::string& title,
                  const std::optional<haptics::MapUnderlay>& underlay, double& mapLo, double& mapHi,
                  std::optional<haptics::MapLayout>& layout, double kMax) {
    std::optional<haptics::ScalarMap> map;
    if (!a.map.empty()) {
        map = haptics::binSnapshots(snaps, mapPlane(a, f, press),
                                    haptics::parseMapQuantity(a.mapQuantity), true,
                                    haptics::parseMapAnchor(a.mapAt));
        map->fillGaps(2);
        map->range(mapLo, mapHi);
    }
    if (!a.trace.empty()) haptics::writeTraceCsv(a.trace, snaps);
    if (!map) return;
    // A figure a clinician can read: axes in mm, patient directions, colour bar, title, the
    // underlay; SVG keeps its text as text, PNG is drawn with cairo from the same layout.
    haptics::MapFigure fig;
    fig.title = title;
    fig.quantity = a.mapQuantity;
    fig.units = a.mapQuantity == "stiffness" ? "N/m" : "N";
    if (a.mapQuantity == "stiffness" && mapHi >= kMax * (1 - 1e-6)) {
        // The stiffest cells hit the device's limit: say so where the scale ends.
        fig.units += "; " + formatValue(kMax) + " = the device's k_max";
    }
    fig.colorMap = a.grey ? haptics::ColorMap::Grey : haptics::ColorMap::Heat;
    fig.underlay = underlay;
    try {
        std::string ext = fs::path(a.map).extension().string();
        std::transform(ext.begin(), ext.end(), ext.begin(),
                       [](unsigned char c) { return static_cast<char>(std::tolower(c)); });
        if (ext == ".svg") {
            haptics::writeMapSvg(a.map, *map, fig);
            layout = haptics::layoutMapFigure(*map, fig, 1.0);
        } else {
            haptics::writeMapFigurePng(a.map, *map, fig, haptics::kMapPngScale);
            layout = haptics::layoutMapFigure(*map, fig, haptics::kMapPngScale);
        }
    } catch (...) {
        if (!a.trace.empty()) {
            std::error_code ec;
            fs::remove(a.trace, ec);
        }
        throw;
    }
}

/// What the report prints.
struct Report {
    std::string label;
    const haptics::DeviceSpec* spec = nullptr;
    haptics::CouplingParams cp;
    double kMaxAsked = 0;
    PathFrame frame;
    std::shared_ptr<const haptics::DeformableModel> body;
    RunResult run;
    std::optional<fem::AsyncSecondaryStats> secondary;  ///< the regions' secondary, after the run
    haptics::RunSummary sum;
    haptics::EnergyBudget budget;  ///< from the end of the approach on
    double mapLo = NAN, mapHi = NAN;
    SkinPlan skin;
    double pressedFrom = 0;               ///< when the path rests pressed (after the approach), s
    double contactAfterApproach = 0;      ///< share of ticks in contact from then on
    std::string underlay, underlayUnits;  ///< the map's underlay ("": none) and its units
    double underlayLo = NAN, underlayHi = NAN;
    std::optional<haptics::MapLayout> figure;  ///< where the map lies in its figure
    haptics::SolverChoice solver;              ///< deformable: the solver and why
    double setupSeconds = 0;                   ///< deformable: voxelise to first layout, s
    ErrorBudgetReport error{};                 ///< --error-budget: the choice and the estimate
};

/// Share of the ticks from @p from (s) on whose proxy is on a surface.
double contactFrom(const std::vector<haptics::Snapshot>& snaps, double from) {
    const auto first = std::find_if(snaps.begin(), snaps.end(), [from](const haptics::Snapshot& s) {
        return s.timeSeconds >= from;
    });
    if (first == snaps.end()) return 0;
    const auto n = static_cast<std::size_t>(snaps.end() - first);
    return haptics::summarize(std::span<const haptics::Snapshot>(&*first, n)).contactFraction;
}

/// What --json says of the skin the path followed.
json skinJson(const Report& r) {
    const SkinPlan& sk = r.skin;
    json j = {{"following", sk.follow}, {"press_axis", axisName(sk.press)}};
    if (!sk.follow) return j;
    j["press_axis_chosen"] = sk.pressChosen ? "side with the most skin facing the press" : "given";
    if (sk.patch) {
        const Eigen::Vector3d c = sk.patch->centre * 1e3;
        j["patch"] = {{"centre_mm", {c.x(), c.y(), c.z()}},
                      {"extent_mm", {sk.patch->extentU * 1e3, sk.patch->extentV * 1e3}},
                      {"facing_fraction", sk.patch->facingFraction}};
    }
    if (sk.field) {
        j["field_hit_fraction"] = sk.field->hitFraction();
        j["field_cell_mm"] = sk.field->spec().cellM * 1e3;
    }
    return j;
}

double ticksPerSecond(const Report& r) {
    return r.run.wallSeconds > 0 ? static_cast<double>(r.run.snaps.size()) / r.run.wallSeconds : 0;
}

double maxDisplacement(const std::vector<haptics::Snapshot>& snaps) {
    double maxDisp = 0;
    for (const auto& s : snaps) maxDisp = std::max(maxDisp, s.maxDisplacement);
    return maxDisp;
}

void printJson(const PalpateArgs& a, const Report& r) {
    const std::string& label = r.label;
    const haptics::DeviceSpec* spec = r.spec;
    const haptics::CouplingParams& cp = r.cp;
    const haptics::RunSummary& sum = r.sum;
    const std::string& tk = a.trajectory;
    const double kMaxAsked = r.kMaxAsked, wallSeconds = r.run.wallSeconds, tps = ticksPerSecond(r);
    const double mapLo = r.mapLo, mapHi = r.mapHi;
    const Eigen::Vector3d& v = r.frame.v;
    const json& loopJson = r.run.loopJson;
    const auto& body = r.body;
    json j;
    j["input"] = label;
    j["device"] = std::string(spec->name);
    j["mode"] = haptics::couplingModeName(cp.mode);
    j["source"] = haptics::raySourceName(cp.source);
    j["trajectory"] = tk;
    j["k_base_npm"] = cp.baseStiffness;
    j["k_max_npm"] = cp.maxStiffness;
    j["k_max_asked_npm"] = kMaxAsked;
    j["l_max_mm"] = cp.bundle.length * 1e3;
    j["l_ref_mm"] = cp.referenceLength * 1e3;
    if (cp.mode == haptics::CouplingMode::AVCEC) j["max_ray_tilt_rad"] = cp.maxRayTilt;
    j["realtime"] = a.realtime;
    j["ticks"] = sum.ticks;
    j["simulated_seconds"] = sum.seconds;
    j["wall_seconds"] = wallSeconds;
    if (!a.realtime) j["ticks_per_second"] = tps;
    if (a.realtime) j["servo"] = loopJson;
    j["rays_per_frame_mean"] = sum.meanRays;
    j["rays_per_frame_max"] = sum.maxRays;
    j["max_force_n"] = sum.maxForceN;
    j["observer_energy_final_j"] = sum.finalObserverEnergy;
    j["observer_energy_min_j"] = sum.minObserverEnergy;
    const haptics::EnergyBudget& e = r.budget;
    j["energy_budget_mj"] = {
        {"hand_work", e.handWork * 1e3},      {"probe_work", e.probeWork * 1e3},
        {"proxy_work", e.proxyWork * 1e3},    {"stored_change", e.storedChange * 1e3},
        {"created", e.created * 1e3},         {"rendering", e.rendering * 1e3},
        {"proxy_path_mm", e.proxyPath * 1e3}, {"probe_path_mm", e.probePath * 1e3}};
    j["contact_fraction"] = sum.contactFraction;
    j["contact_fraction_after_approach"] = r.contactAfterApproach;
    j["path_pressed_from_s"] = r.pressedFrom;
    j["skin"] = skinJson(r);
    // What the hand felt over the patch, in fingertip-sized cells (4 mm, or two raster lines).
    j["felt"] =
        feltSummary(r.run.snaps, r.frame, std::max(4e-3, 2e-3 * a.spacingMm), r.pressedFrom);
    j["stiffness_min_npm"] = sum.minStiffness;
    j["stiffness_max_npm"] = sum.maxStiffness;
    j["faulted_ticks"] = sum.faultedTicks;
    j["clamped_ticks"] = sum.clampedTicks;
    j["interrupted"] = r.run.interrupted != 0;
    if (body) {
        const double maxDisp = maxDisplacement(r.run.snaps);
        const fem::HexMesh& mesh = body->model().mesh();
        const bool regions = body->options().solverKind == haptics::DeformableSolver::asyncRegions;
        j["deformable"] = {{"nodes", activeNodes(mesh)},
                           {"lattice_nodes", mesh.nodeCount()},
                           {"elements", mesh.elementCount()},
                           {"surface_triangles", body->surface().triangles.size()},
                           {"fixed_nodes", body->fixedNodes().size()},
                           {"filter_mm", a.filterMm},
                           {"recontact_ms", a.recontactMs},
                           {"recontact_rise_nps", a.recontactRiseNps},
                           {"cell_mm", a.femCellMm},
                           {"young_kpa", a.materialTable.empty() ? json(a.youngKpa) : json()},
                           {"material", a.material},
                           {"material_table", materialTableJson(a)},
                           {"solver", regions ? "regions" : "explicit"},
                           {"solver_asked", a.femSolver},
                           {"solver_reason", r.solver.reason},
                           {"pieces_kept", body->keptPieces().size()},
                           {"pieces_dropped", body->droppedPieces().size()},
                           {"cells_dropped", pieceCells(body->droppedPieces())},
                           {"setup_seconds", r.setupSeconds},
                           {"peak_rss_mib", peakRssMiB()},
                           {"max_displacement_mm", maxDisp * 1e3}};
        if (regions) {
            j["deformable"]["lod"] = body->options().regions.lod;
            // The skin the contact slides over without a factorisation per move (0: the
            // lattice face of the regions centre, a phantom's).
            j["deformable"]["slide_nodes"] = body->options().regions.slideNodes.size();
            j["deformable"]["seeds"] = body->options().regions.primaryNodes;
            // The secondary region as it ran: its rate asked and reached, its solves taken up
            // by the primary, its longest solve, and the layouts prepared as the contact moved.
            if (r.secondary) {
                const fem::AsyncSecondaryStats& st = *r.secondary;
                j["deformable"]["secondary"] = {
                    {"rate_hz_asked", body->options().regions.secondaryRate},
                    {"solves_per_s",
                     sum.seconds > 0 ? static_cast<double>(st.solves) / sum.seconds : 0.0},
                    {"solves", st.solves},
                    {"used", st.used},
                    {"max_solve_ms", 1e3 * st.maxSolveSeconds},
                    {"layouts_prepared", st.layoutsPrepared}};
            }
        }
    }
    if (body) j["error_budget"] = errorBudgetJson(r.error);
    if (!a.trace.empty()) j["trace"] = a.trace;
    if (!a.map.empty()) {
        j["map"] = a.map;
        j["map_quantity"] = a.mapQuantity;
        j["map_at"] = a.mapAt;
        j["map_range"] = {mapLo, mapHi};
        j["map_right"] = axisName(mapRight(r.frame, r.skin.press));
        j["map_up"] = axisName(v);
        j["map_underlay"] = r.underlay.empty() ? json("none") : json(r.underlay);
        if (r.figure) {
            // Where the map lies in the image (px from the top left) and the world mm at its
            // edges, so that a reader can measure on it.
            const haptics::MapLayout& l = *r.figure;
            j["map_image"] = {{"width_px", std::ceil(l.width)},
                              {"height_px", std::ceil(l.height)},
                              {"map_px", {l.mapX, l.mapY, l.mapW, l.mapH}},
                              {"u_mm", {l.mmAtX(l.mapX), l.mmAtX(l.mapX + l.mapW)}},
                              {"v_mm", {l.mmAtY(l.mapY + l.mapH), l.mmAtY(l.mapY)}}};
        }
        if (!r.underlay.empty())
            j["map_underlay_range"] = {r.underlayLo, r.underlayHi, r.underlayUnits};
    }
    std::printf("%s\n", j.dump(2).c_str());
}

void printText(const PalpateArgs& a, const Report& r) {
    const std::string& label = r.label;
    const haptics::DeviceSpec* spec = r.spec;
    const haptics::CouplingParams& cp = r.cp;
    const haptics::RunSummary& sum = r.sum;
    const std::string& tk = a.trajectory;
    const double wallSeconds = r.run.wallSeconds, tps = ticksPerSecond(r);
    const double mapLo = r.mapLo, mapHi = r.mapHi;
    const Eigen::Vector3d& v = r.frame.v;
    const auto& snaps = r.run.snaps;
    const auto& body = r.body;
    std::printf(
        "palp palpate: %s, %s/%s, %s on %s, k_s %.0f N/m, k_max %.0f "
        "N/m, L_max %.0f mm, L_ref %.0f mm\n",
        label.c_str(), haptics::couplingModeName(cp.mode), haptics::raySourceName(cp.source),
        tk.c_str(), std::string(spec->name).c_str(), cp.baseStiffness, cp.maxStiffness,
        cp.bundle.length * 1e3, cp.referenceLength * 1e3);
    if (a.realtime) {
        std::printf("%s\n", r.run.loopText.c_str());
        std::printf("trace: %zu snapshots, %llu dropped\n", snaps.size(),
                    static_cast<unsigned long long>(r.run.traceDropped));
    } else {
        std::printf(
            "fast: %llu ticks (%.2f s simulated) in %.3f s wall: %.0f "
            "ticks/s\n",
            static_cast<unsigned long long>(sum.ticks), sum.seconds, wallSeconds, tps);
    }
    if (r.skin.follow) {
        std::printf("path on the skin: pressed along %s%s", axisName(r.skin.press).c_str(),
                    r.skin.pressChosen ? " (the side with the most skin facing it)" : "");
        if (r.skin.patch)
            std::printf(", patch %.0f x %.0f mm centred at (%.1f, %.1f, %.1f) mm",
                        r.skin.patch->extentU * 1e3, r.skin.patch->extentV * 1e3,
                        r.skin.patch->centre.x() * 1e3, r.skin.patch->centre.y() * 1e3,
                        r.skin.patch->centre.z() * 1e3);
        std::printf("\n");
    }
    std::printf(
        "rays per frame: mean %.1f, max %d; in contact %.0f %% of ticks (%.0f %% after the "
        "approach); stiffness %.0f-%.0f N/m\n",
        sum.meanRays, sum.maxRays, 100 * sum.contactFraction, 100 * r.contactAfterApproach,
        sum.minStiffness, sum.maxStiffness);
    std::printf(
        "max force %.3f N (%llu ticks clamped, %llu faulted); passivity "
        "observer W: final %.3g J, min %.3g J\n",
        sum.maxForceN, static_cast<unsigned long long>(sum.clampedTicks),
        static_cast<unsigned long long>(sum.faultedTicks), sum.finalObserverEnergy,
        sum.minObserverEnergy);
    if (body) {
        const double maxDisp = maxDisplacement(snaps);
        std::printf(
            "deformable: %d nodes, %d elements, %zu surface triangles, %zu fixed "
            "nodes (support + bone), filter %.1f mm, %s, %s; largest "
            "surface displacement %.2f mm; set up in %.1f s, peak memory %.0f MiB\n",
            activeNodes(body->model().mesh()), body->model().mesh().elementCount(),
            body->surface().triangles.size(), body->fixedNodes().size(), a.filterMm,
            ((a.material == "neo-hookean" ? "neo-Hookean, " : "linear, ") +
             (a.materialTable.empty() ? "E " + formatValue(a.youngKpa) + " kPa"
                                      : "E from the table " + a.materialTable))
                .c_str(),
            r.solver.reason.c_str(), maxDisp * 1e3, r.setupSeconds, peakRssMiB());
        if (!body->droppedPieces().empty()) {
            const fem::BodyPiece& p = body->droppedPieces().front();
            std::printf(
                "deformable: kept %zu piece(s) the supports hold; dropped %zu piece(s) nothing "
                "holds (%ld cells; largest %d cells at (%.0f, %.0f, %.0f) mm)\n",
                body->keptPieces().size(), body->droppedPieces().size(),
                pieceCells(body->droppedPieces()), p.cells, 500 * (p.lo.x() + p.hi.x()),
                500 * (p.lo.y() + p.hi.y()), 500 * (p.lo.z() + p.hi.z()));
        }
        printErrorBudget(r.error);
    }
    const json felt =
        feltSummary(r.run.snaps, r.frame, std::max(4e-3, 2e-3 * a.spacingMm), r.pressedFrom);
    if (felt.contains("stiffest")) {
        const json& st = felt["stiffest"];
        std::printf(
            "felt: stiffest %.0f N/m at (%.1f, %.1f, %.1f) mm, hard structure %.1f mm "
            "under it by the rays",
            st["stiffness_npm"].get<double>(), st["at_mm"][0].get<double>(),
            st["at_mm"][1].get<double>(), st["at_mm"][2].get<double>(),
            st["hard_depth_mm"].get<double>());
        if (felt.contains("stiffness_vs_hard_depth_spearman") &&
            felt["stiffness_vs_hard_depth_spearman"].is_number())
            std::printf("; stiffness vs that depth over %d cells of %.0f mm: Spearman %.2f",
                        felt["cells"].get<int>(), felt["cell_mm"].get<double>(),
                        felt["stiffness_vs_hard_depth_spearman"].get<double>());
        std::printf("\n");
    }
    if (!a.trace.empty()) std::printf("wrote %s\n", a.trace.c_str());
    if (!a.map.empty()) {
        std::printf("wrote %s: %s from %.3g to %.3g; image right = %s, up = %s", a.map.c_str(),
                    a.mapQuantity.c_str(), mapLo, mapHi,
                    axisName(mapRight(r.frame, r.skin.press)).c_str(), axisName(v).c_str());
        if (!r.underlay.empty())
            std::printf("; under it %s %.3g-%.3g %s", r.underlay.c_str(), r.underlayLo,
                        r.underlayHi, r.underlayUnits.c_str());
        std::printf("\n");
    }
}

/// `palp palpate`: checks, set-up, run, outputs, report.
int runPalpate(PalpateArgs a, const CheckedOptions& o) {
    const haptics::DeviceSpec* spec = checkPalpateOptions(a, o);
    liveHeap();

    // Volume and coupling.
    Input in = loadInput(a);
    if (!in.phantom) {
        // A scan without HU (an MR): its own skin and tissue threshold, no bone, no hard
        // structure for the rays, where the user left the CT defaults.
        const ScanDefaults d = scanDefaults(in.vol);
        if (d.applies) {
            if (!o.surfaceIso->count()) a.surfaceIso = d.threshold;
            if (!o.tissueHu->count()) a.tissueHu = d.threshold;
            if (!o.boneHu->count()) a.boneHu = std::numeric_limits<double>::infinity();
            if (!o.threshold->count())
                in.cp.firstHit.threshold = static_cast<float>(d.greatest) + 1;
            if (!a.json && !globals().quiet)
                std::printf("scan without HU (%s): skin and tissue above %.4g (Otsu), no bone\n",
                            in.vol.info.modality.empty() ? "modality unknown"
                                                         : in.vol.info.modality.c_str(),
                            d.threshold);
        }
    }
    const volume::Volume& vol = in.vol;
    haptics::CouplingParams cp = couplingFromOptions(a, in.cp);
    haptics::validateCouplingParams(cp);
    const double period = 1e-3;
    const double kMaxAsked = cp.maxStiffness;
    haptics::limitStiffnessToDevice(cp, *spec, period);

    haptics::SceneOptions so;
    so.surfaceIso = a.surfaceIso;
    if (cp.source == haptics::RaySource::Mesh) so.hardIso = cp.firstHit.threshold;
    if (a.deformable) so.surfaceIso = std::numeric_limits<double>::quiet_NaN();
    auto scene = haptics::Scene::fromVolume(vol, so);

    // The path: on a scan, laid on the skin of the side that faces the press the most; on a
    // phantom, the face of the volume against the press. A deformable scan's side and patch
    // come from the scan's iso-surface (its scene has none: the proxy slides on the body), the
    // heights under the path from the body's own surface at rest, which the proxy meets.
    const Eigen::AlignedBox3d box = volumeBox(vol, in.label);
    std::shared_ptr<haptics::Scene> skinScene = scene;
    if (a.deformable && followsSkin(a, in)) {
        haptics::SceneOptions iso;
        iso.surfaceIso = a.surfaceIso;
        skinScene = haptics::Scene::fromVolume(vol, iso);
    }
    SkinPlan skin = planSkin(a, o.pressAxis->count() > 0, in, skinScene->surfaces(), box);
    skinScene.reset();
    const Eigen::Vector3d press = skin.press;
    PathFrame frame = pathFrame(a, box, press, skin.patch ? &*skin.patch : nullptr);
    std::shared_ptr<const haptics::DeformableModel> body;
    haptics::SolverChoice solver;
    // The body's set-up: voxelise, assemble, and (in the session) factorise and lay out.
    const auto setupStart = std::chrono::steady_clock::now();
    if (a.deformable) {
        try {
            // The skin under the path (with room for the raster's turns and the filter) is
            // what the regions' contact slides over; a phantom's is its lattice face.
            std::optional<haptics::SlidePatch> slide;
            if (skin.follow && !in.phantom) {
                const double margin = 2 * a.spacingMm * 1e-3 + 8e-3 + 2 * a.filterMm * 1e-3;
                slide = haptics::SlidePatch{
                    frame.centre,          frame.u, frame.v, press, frame.extentU + margin,
                    frame.extentV + margin};
            }
            body = makeBody(a, in, press, frame.centre, period, &solver, slide ? &*slide : nullptr);
        } catch (const ValueError& e) {
            // Say which options made the tissue (the library speaks of fields, not flags).
            throw ValueError(std::string(e.what()) + "\n(the tissue of --fem-cell-mm " +
                             formatValue(a.femCellMm) + ", --tissue-hu " + formatValue(a.tissueHu) +
                             ", --bone-hu " + formatValue(a.boneHu) + ", --material " + a.material +
                             (a.materialTable.empty() ? ", --young-kpa " + formatValue(a.youngKpa) +
                                                            ", --poisson " + formatValue(a.poisson)
                                                      : ", --material-table " + a.materialTable) +
                             ", --fem-damping " + formatValue(a.femAlpha) + ", --fem-beta " +
                             formatValue(a.femBeta) + ", --filter-mm " + formatValue(a.filterMm) +
                             ")");
        }
        scene->setDeformable(body);
    }
    if (body && skin.follow) {
        measureSkin(a, *haptics::restSurfaceScene(*body), box, frame, skin);
    } else {
        measureSkin(a, scene->surfaces(), box, frame, skin);
    }
    const PathPlan plan = trajectoryFromOptions(a, frame, press, skin.field);
    double duration = plan.duration;
    if (a.seconds > 0) {
        duration = a.seconds;
    } else if (!bounds::kDuration.contains(duration)) {
        // A path that would run for days (a 1 um raster spacing, a crawl of a speed).
        throwExpected("--trajectory " + a.trajectory,
                      "a path done within " + formatValue(bounds::kDuration.max) +
                          " s (raise --spacing or --speed, or set --seconds)",
                      formatValue(duration) + " s");
    }
    std::optional<haptics::MapUnderlay> underlay;
    if (!a.map.empty()) {
        haptics::validateMapPlane(mapPlane(a, frame, press));
        underlay =
            mapUnderlay(a, in, *scene, mapPlane(a, frame, press), press, box, cp.bundle.length);
    }
    const auto ticks = static_cast<std::uint64_t>(std::ceil(duration / period));

    haptics::SessionParams sp;
    sp.coupling = cp;
    sp.proxy.staticFriction = a.muStatic;
    sp.proxy.dynamicFriction = std::isfinite(a.muDynamic) ? a.muDynamic : std::min(0.3, a.muStatic);
    if (sp.proxy.dynamicFriction > sp.proxy.staticFriction) {
        throwExpected("--mu-dynamic", "at most --mu-static (" + formatValue(a.muStatic) + ")",
                      formatValue(sp.proxy.dynamicFriction));
    }
    sp.passivityControl = a.passivityControl;
    sp.recontact.seconds = 1e-3 * a.recontactMs;
    sp.recontact.riseNps = a.recontactRiseNps;
    sp.servo.periodSeconds = period;
    a.servo.applyTo(sp.servo);
    // Real time: every tick's snapshot is queued in the trace ring and drained below
    // (16 Ki snapshots: seconds of slack at servo rates before any is dropped).
    if (a.realtime) sp.traceCapacity = 1u << 14;
    haptics::validateSessionParams(sp);
    haptics::SimulatedDevice device(*spec, plan.traj, haptics::HandModel{}, period);
    haptics::Session session(scene, device, sp);
    const double setupSeconds =
        a.deformable
            ? std::chrono::duration<double>(std::chrono::steady_clock::now() - setupStart).count()
            : 0.0;

    // --seconds under --realtime is wall-clock time (the path's ticks otherwise).
    RunResult run = a.realtime ? runRealtime(session, ticks, a.seconds) : runFast(session, ticks);
    Report r{in.label,
             spec,
             cp,
             kMaxAsked,
             frame,
             body,
             std::move(run),
             std::nullopt,
             {},
             {},
             NAN,
             NAN,
             skin,
             plan.pressedFrom,
             0,
             {},
             {},
             NAN,
             NAN,
             {},
             solver,
             setupSeconds};
    if (r.run.snaps.empty()) {  // stopped before the first tick: nothing to write
        std::fprintf(stderr, "palp palpate: interrupted before the first tick; nothing written\n");
        return 128 + r.run.interrupted;
    }
    r.sum = haptics::summarize(r.run.snaps);
    if (const haptics::DeformableBody* db = session.deformable())
        if (const fem::AsyncRegions* rg = db->regions()) r.secondary = rg->secondaryStats();
    r.contactAfterApproach = contactFrom(r.run.snaps, plan.pressedFrom);
    r.budget = haptics::energyBudget(r.run.snaps, plan.approach);
    r.error = errorBudgetReport(a, body.get(), r.run.snaps, press, period);
    // The map's title: what was palpated, how, along which path.
    const std::string title = (in.phantom ? in.label : fs::path(in.label).filename().string()) +
                              ": " + haptics::couplingModeName(cp.mode) + "/" +
                              haptics::raySourceName(cp.source) + ", " + a.trajectory +
                              (skin.follow ? " on the skin" : "") + ", pressed " + axisName(press) +
                              " (from " + haptics::patientDirection(-press) + ")";
    writeOutputs(a, frame, press, r.run.snaps, title, underlay, r.mapLo, r.mapHi, r.figure,
                 cp.maxStiffness);
    if (underlay) {
        r.underlay = underlay->quantity;
        underlay->map.range(r.underlayLo, r.underlayHi);
        r.underlayUnits = underlay->units;
    }
    if (a.json) {
        printJson(a, r);
    } else if (!globals().quiet) {
        printText(a, r);
    }
    if (r.run.interrupted) {
        std::fprintf(stderr,
                     "palp palpate: interrupted after %zu of %llu ticks; the trace, map and "
                     "summary cover those\n",
                     r.run.snaps.size(), static_cast<unsigned long long>(ticks));
        return 128 + r.run.interrupted;  // as a shell reports a process the signal stopped
    }
    return 0;
}

}  // namespace

int axisIndex(const Eigen::Vector3d& a) {
    int i = 0;
    a.cwiseAbs().maxCoeff(&i);
    return i;
}

Eigen::Vector3d parseAxis(const std::string& text, const char* option) {
    std::string s = text;
    double sign = 1;
    if (!s.empty() && (s[0] == '+' || s[0] == '-')) {
        sign = s[0] == '-' ? -1 : 1;
        s = s.substr(1);
    }
    if (s == "x") return sign * Eigen::Vector3d::UnitX();
    if (s == "y") return sign * Eigen::Vector3d::UnitY();
    if (s == "z") return sign * Eigen::Vector3d::UnitZ();
    throw ValueError(std::string(option) + ": expected an axis +x, -x, +y, -y, +z or -z, found '" +
                     text + "'");
}

Command addPalpate(CLI::App& root) {
    auto args = std::make_shared<PalpateArgs>();
    auto checked = std::make_shared<CheckedOptions>();
    CLI::App* app = root.add_subcommand(
        "palpate",
        "Palpate a volume or a thesis phantom with VC/AVC/AVCEC along a scripted path (simulated "
        "hand and device); write a CSV trace and a PNG map");
    addPalpateOptions(app, *args, *checked);
    return {app, [args, checked]() -> int { return runPalpate(*args, *checked); }};
}

}  // namespace palp::tool
