// palp convert: any supported scan -> sparse, isotropic .vdb in world metres (LPS).
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <vector>

#include "batch_heap.h"
#include "commands.h"
#include "option_checks.h"
#include "palp/base/error.h"
#include "palp/base/validate.h"
#include "palp/volume/load.h"
#include "palp/volume/resample.h"
#include "progress.h"
#include "volume_flags.h"

namespace palp::tool {

namespace fs = std::filesystem;

namespace {

/// @p v moved to the heap and never freed (reachable through a static pointer, so LeakSanitizer
/// does not count it); a second call replaces nothing, it keeps both.
const volume::Volume& keepUntilExit(volume::Volume&& v) {
    static std::vector<volume::Volume*> kept;
    kept.push_back(new volume::Volume(std::move(v)));
    return *kept.back();
}

}  // namespace

Command addConvert(CLI::App& root) {
    struct Args {
        std::vector<std::string> inputs;
        std::string output;
        double voxelMm = 0;
        std::string series;
        int volume = -1;
        double background = std::numeric_limits<double>::quiet_NaN();
        std::vector<double> cropMm;
        std::string compression = "mask";
    };
    auto args = std::make_shared<Args>();
    CLI::App* app = root.add_subcommand(
        "convert",
        "Convert a DICOM series, NIfTI, NRRD, MetaImage or .vdb into a palp .vdb volume");
    app->add_option("inputs", args->inputs, "Input file(s) or a DICOM directory")->required();
    app->add_option("-o,--output", args->output, "Output .vdb file")->required();
    app->add_option("--voxel-size", args->voxelMm,
                    "Isotropic voxel edge in mm (default: finest input spacing)")
        ->check(within(bounds::kSpacing, kMm));
    app->add_option("--series", args->series, "DICOM SeriesInstanceUID to convert");
    app->add_option("--volume", args->volume, "0-based time point of a 4D series or file")
        ->check(integerIn(0, 1000000));
    app->add_option("--background", args->background,
                    "Values below this become inactive background (default -900 for CT, none "
                    "for MR, 0 otherwise); the values lost to it are counted")
        ->check(within(bounds::kVolumeValue));
    app->add_option("--crop", args->cropMm, "World box in mm (LPS): xmin,ymin,zmin,xmax,ymax,zmax")
        ->delimiter(',')
        ->expected(6)
        ->check(within(bounds::kPosition, kMm));
    app->add_option("--compression", args->compression,
                    "Leaf values: mask (default: active values as plain floats, inactive "
                    "dropped), blosc (LZ4: ~15 % smaller for CT, ~3x the write time) or zip "
                    "(~9 % smaller, ~20x the write time)")
        ->check(CLI::IsMember({"blosc", "zip", "mask"}));
    return {
        app, [args]() -> int {
            batchHeap();
            const fs::path out(args->output);
            const fs::path dir = out.has_parent_path() ? out.parent_path() : fs::path(".");
            std::error_code ec;
            if (!fs::is_directory(dir, ec)) {
                throw IoError(out.string() + ": expected an existing directory '" + dir.string() +
                              "' for the output, found none");
            }
            volume::LoadOptions opt;
            if (args->voxelMm > 0) opt.resample.voxelSize = args->voxelMm * 1e-3;
            if (!args->series.empty()) opt.seriesUid = args->series;
            if (args->volume >= 0) opt.timePoint = args->volume;
            if (!std::isnan(args->background))
                opt.resample.backgroundThreshold = static_cast<float>(args->background);
            if (!args->cropMm.empty()) {
                const std::vector<double>& c = args->cropMm;
                if (!(c[0] < c[3] && c[1] < c[4] && c[2] < c[5])) {
                    throwExpected("--crop", "xmin < xmax, ymin < ymax and zmin < zmax (mm)",
                                  formatValue(c[0]) + "," + formatValue(c[1]) + "," +
                                      formatValue(c[2]) + "," + formatValue(c[3]) + "," +
                                      formatValue(c[4]) + "," + formatValue(c[5]));
                }
                volume::WorldBox box;
                box.min = Eigen::Vector3d(args->cropMm[0], args->cropMm[1], args->cropMm[2]) * 1e-3;
                box.max = Eigen::Vector3d(args->cropMm[3], args->cropMm[4], args->cropMm[5]) * 1e-3;
                opt.resample.crop = box;
            }
            opt.resample.progress = progressLine("palp convert: resampling");
            std::vector<fs::path> inputs(args->inputs.begin(), args->inputs.end());
            // Held to the end of the process: the grid is left to the kernel at exit. Freeing its
            // leaves one by one (73,636 of them, each with its buffer, for the head CT at 0.5 mm)
            // was ~3 % of convert's CPU samples, for memory the process returns anyway.
            const volume::Volume& vol =
                keepUntilExit(withVolumeFlags([&] { return volume::load(inputs, opt); }));
            endProgress();
            volume::SaveOptions so;
            so.compression = args->compression == "zip"    ? volume::Compression::Zip
                             : args->compression == "mask" ? volume::Compression::ActiveMask
                                                           : volume::Compression::Blosc;
            volume::save(vol, out, so);
            if (!globals().quiet) {
                const auto b = vol.worldBounds();
                std::printf(
                    "palp convert: wrote %s: %s %s, voxel %.4g mm, %llu active voxels, "
                    "world box (%.1f, %.1f, %.1f) - (%.1f, %.1f, %.1f) mm\n",
                    out.c_str(), vol.info.sourceFormat.c_str(), vol.info.modality.c_str(),
                    vol.voxelSize() * 1e3,
                    static_cast<unsigned long long>(vol.grid->activeVoxelCount()),
                    b.min().x() * 1e3, b.min().y() * 1e3, b.min().z() * 1e3, b.max().x() * 1e3,
                    b.max().y() * 1e3, b.max().z() * 1e3);
                // Every value the background threshold took away is counted (issue 37: MR
                // field maps and phase images lost their negative values without a word).
                if (vol.info.backgroundThreshold <= volume::kNoBackgroundThreshold) {
                    std::printf(
                        "palp convert: no background threshold: no source value deactivated\n");
                } else {
                    std::printf(
                        "palp convert: background threshold %.6g: %llu source values below it "
                        "now read as the background %.6g\n",
                        static_cast<double>(vol.info.backgroundThreshold),
                        static_cast<unsigned long long>(vol.info.valuesBelowThreshold),
                        static_cast<double>(vol.grid->background()));
                }
            }
            return 0;
        }};
}

}  // namespace palp::tool
