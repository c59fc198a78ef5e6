// palp info: what a .vdb, a DICOM directory or a scan file holds.
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <limits>
#include <nlohmann/json.hpp>
#include <vector>

#include "batch_heap.h"
#include "commands.h"
#include "palp/base/error.h"
#include "palp/base/parallel.h"
#include "palp/volume/dicom.h"
#include "palp/volume/load.h"
#include "palp/volume/resample.h"
#include "volume_flags.h"

namespace palp::tool {

namespace fs = std::filesystem;
using nlohmann::json;

namespace {

/// Millimetre figures rounded to 1 nm, so that float noise of the metre-based geometry
/// (0.5000000000000004) does not show.
double mm(double v) { return std::round(v * 1e6) / 1e6; }

json vec3(double a, double b, double c) { return json::array({mm(a), mm(b), mm(c)}); }

json volumeJson(const volume::Volume& v, const fs::path& path) {
    const auto& g = *v.grid;
    const openvdb::CoordBBox ibox = g.evalActiveVoxelBoundingBox();
    const auto wb = v.worldBounds();
    // Statistics of the active values: per leaf in parallel, then summed in tree order (the
    // same sums whatever the thread count); an active tile counts once per voxel it covers.
    struct Stats {
        double mn = std::numeric_limits<double>::infinity(), mx = -mn, sum = 0, sum2 = 0;
        std::uint64_t n = 0;
        void add(double x, std::uint64_t count) {
            mn = std::min(mn, x);
            mx = std::max(mx, x);
            sum += x * static_cast<double>(count);
            sum2 += x * x * static_cast<double>(count);
            n += count;
        }
        void add(const Stats& o) {
            mn = std::min(mn, o.mn);
            mx = std::max(mx, o.mx);
            sum += o.sum;
            sum2 += o.sum2;
            n += o.n;
        }
    };
    Stats total;
    auto tiles = g.cbeginValueOn();
    tiles.setMaxDepth(openvdb::FloatTree::ValueOnCIter::LEAF_DEPTH - 1);
    for (; tiles; ++tiles) total.add(*tiles, tiles.getVoxelCount());
    std::vector<const openvdb::FloatTree::LeafNodeType*> leaves;
    leaves.reserve(g.tree().leafCount());
    for (auto it = g.tree().cbeginLeaf(); it; ++it) leaves.push_back(it.getLeaf());
    std::vector<Stats> perLeaf(leaves.size());
    palp::parallelForEach(
        std::size_t{0}, leaves.size(),
        [&](std::size_t i) {
            for (auto it = leaves[i]->cbeginValueOn(); it; ++it) perLeaf[i].add(*it, 1);
        },
        std::size_t{64});
    for (const Stats& s : perLeaf) total.add(s);
    const double mn = total.mn, mx = total.mx, sum = total.sum, sum2 = total.sum2;
    const std::uint64_t n = total.n;
    const double mean = n ? sum / static_cast<double>(n) : 0.0;
    const double sd =
        n ? std::sqrt(std::max(0.0, sum2 / static_cast<double>(n) - mean * mean)) : 0.0;
    const auto& i = v.info;
    json j;
    j["file"] = path.string();
    j["grid"] = g.getName();
    // voxel_size_mm: the cubic edge (the smallest edge of native spacing's non-cubic voxels,
    // which load() re-grids to); voxel_sizes_mm: the edges along index x, y, z as stored.
    j["voxel_size_mm"] = v.voxelSize() * 1e3;
    const openvdb::Vec3d edges = v.voxelSizes();
    j["voxel_sizes_mm"] = vec3(edges[0] * 1e3, edges[1] * 1e3, edges[2] * 1e3);
    j["active_voxels"] = n;
    j["memory_bytes"] = g.memUsage();
    j["background_value"] = g.background();
    j["background_threshold"] = i.backgroundThreshold;
    if (!ibox.empty()) {
        j["index_box"] = {vec3(ibox.min().x(), ibox.min().y(), ibox.min().z()),
                          vec3(ibox.max().x(), ibox.max().y(), ibox.max().z())};
        j["dimensions"] = vec3(ibox.dim().x(), ibox.dim().y(), ibox.dim().z());
        j["world_box_mm"] = {vec3(wb.min().x() * 1e3, wb.min().y() * 1e3, wb.min().z() * 1e3),
                             vec3(wb.max().x() * 1e3, wb.max().y() * 1e3, wb.max().z() * 1e3)};
        j["values"] = {{"min", mn}, {"max", mx}, {"mean", mean}, {"stddev", sd}};
    }
    j["metadata"] = {
        {"modality", i.modality},
        {"value_units", i.valueUnits},
        {"source_format", i.sourceFormat},
        {"source_description", i.sourceDescription},
        {"series_uid", i.seriesUid},
        {"original_dims", i.originalDims},
        {"original_spacing_mm",
         vec3(i.originalSpacing[0] * 1e3, i.originalSpacing[1] * 1e3, i.originalSpacing[2] * 1e3)},
        {"slice_gap_mm", {mm(i.minSliceGap * 1e3), mm(i.maxSliceGap * 1e3)}},
        {"rescale", {{"slope", i.rescaleSlope}, {"intercept", i.rescaleIntercept}}},
        {"gantry_tilt_deg", i.gantryTiltDeg},
        {"time_point", i.timePoint},
        {"time_point_count", i.timePointCount}};
    // As dcm2niix's sidecar names it; only GE EPI series have it.
    if (!i.phaseEncodingPolarityGE.empty())
        j["metadata"]["phase_encoding_polarity_ge"] = i.phaseEncodingPolarityGE;
    return j;
}

void printVolume(const json& j) {
    std::printf("%s\n", j["file"].get<std::string>().c_str());
    const auto& e = j["voxel_sizes_mm"];
    char voxel[96];
    if (e[0] == e[1] && e[1] == e[2]) {
        std::snprintf(voxel, sizeof voxel, "%.4g", e[0].get<double>());
    } else {
        std::snprintf(voxel, sizeof voxel, "%.4g x %.4g x %.4g", e[0].get<double>(),
                      e[1].get<double>(), e[2].get<double>());
    }
    std::printf("  grid            %s, voxel %s mm, %llu active voxels, %.1f MiB in memory\n",
                j["grid"].get<std::string>().c_str(), voxel,
                static_cast<unsigned long long>(j["active_voxels"].get<std::uint64_t>()),
                static_cast<double>(j["memory_bytes"].get<std::uint64_t>()) / (1024.0 * 1024.0));
    if (j.contains("dimensions")) {
        const auto& d = j["dimensions"];
        const auto& w = j["world_box_mm"];
        std::printf("  dimensions      %d x %d x %d voxels (active bounding box)\n",
                    d[0].get<int>(), d[1].get<int>(), d[2].get<int>());
        std::printf("  world box (LPS) (%.2f, %.2f, %.2f) - (%.2f, %.2f, %.2f) mm\n",
                    w[0][0].get<double>(), w[0][1].get<double>(), w[0][2].get<double>(),
                    w[1][0].get<double>(), w[1][1].get<double>(), w[1][2].get<double>());
        const auto& s = j["values"];
        std::printf("  values          min %.6g, max %.6g, mean %.6g, stddev %.6g\n",
                    s["min"].get<double>(), s["max"].get<double>(), s["mean"].get<double>(),
                    s["stddev"].get<double>());
    }
    if (j["background_threshold"].get<double>() <= volume::kNoBackgroundThreshold) {
        std::printf("  background      %.6g (no threshold: every value is kept)\n",
                    j["background_value"].get<double>());
    } else {
        std::printf("  background      %.6g (values below %.6g are inactive)\n",
                    j["background_value"].get<double>(), j["background_threshold"].get<double>());
    }
    const auto& m = j["metadata"];
    for (auto it = m.begin(); it != m.end(); ++it) {
        std::printf("  %-15s %s\n", it.key().c_str(), it.value().dump().c_str());
    }
}

}  // namespace

Command addInfo(CLI::App& root) {
    struct Args {
        std::string input;
        bool json = false;
    };
    auto args = std::make_shared<Args>();
    CLI::App* app =
        root.add_subcommand("info", "Describe a .vdb volume, a DICOM directory or a scan file");
    app->add_option("input", args->input, "A .vdb, a DICOM directory or file, or a scan file")
        ->required();
    app->add_flag("--json", args->json, "Print JSON");
    return {app, [args]() -> int {
                batchHeap();
                const fs::path in(args->input);
                std::error_code ec;
                if (!fs::exists(in, ec)) {
                    throw IoError(in.string() +
                                  ": expected an existing file or directory, found nothing");
                }
                const volume::Format f = volume::detectFormat(in);
                json j;
                if (f == volume::Format::Vdb) {
                    j = volumeJson(volume::loadVdb(in), in);
                    if (!args->json) printVolume(j);
                } else if (f == volume::Format::Dicom) {
                    const auto series = volume::scanDicom({in});
                    j["file"] = in.string();
                    j["series"] = json::array();
                    for (const auto& s : series) {
                        j["series"].push_back({{"uid", s.uid},
                                               {"description", s.description},
                                               {"modality", s.modality},
                                               {"images", s.imageCount},
                                               {"frames", s.frameCount},
                                               {"positions", s.positionCount},
                                               {"time_points", s.timePointCount}});
                        if (!s.problem.empty()) j["series"].back()["problem"] = s.problem;
                    }
                    if (!args->json) {
                        std::printf("%s: %zu DICOM series\n", in.c_str(), series.size());
                        for (const auto& s : series) {
                            // Enhanced multi-frame files: the frames are what is grouped.
                            const std::string frames =
                                s.frameCount != s.imageCount
                                    ? " (" + std::to_string(s.frameCount) + " frames)"
                                    : std::string();
                            std::printf(
                                "  %s  %-4s %4d images%s, %4d positions, %3d time points  "
                                "\"%s\"\n",
                                s.uid.c_str(), s.modality.c_str(), s.imageCount, frames.c_str(),
                                s.positionCount, s.timePointCount, s.description.c_str());
                            if (!s.problem.empty())
                                std::printf("    cannot be converted: %s\n", s.problem.c_str());
                        }
                    }
                } else {
                    volume::LoadOptions opt;
                    opt.timePoint = 0;  // describe the first volume of 4D files
                    const volume::SliceStack st =
                        withVolumeFlags([&] { return volume::readStack({in}, opt); });
                    const auto& sl = st.slices.front();
                    j["file"] = in.string();
                    j["format"] = st.info.sourceFormat;
                    j["dims"] = vec3(sl.cols, sl.rows, static_cast<double>(st.slices.size()));
                    j["column_step_mm"] =
                        vec3(sl.colStep.x() * 1e3, sl.colStep.y() * 1e3, sl.colStep.z() * 1e3);
                    j["row_step_mm"] =
                        vec3(sl.rowStep.x() * 1e3, sl.rowStep.y() * 1e3, sl.rowStep.z() * 1e3);
                    j["first_slice_mm"] =
                        vec3(sl.position.x() * 1e3, sl.position.y() * 1e3, sl.position.z() * 1e3);
                    j["time_points"] = st.info.timePointCount;
                    if (!args->json) std::printf("%s\n", j.dump(2).c_str());
                }
                if (args->json) std::printf("%s\n", j.dump(2).c_str());
                return 0;
            }};
}

}  // namespace palp::tool
