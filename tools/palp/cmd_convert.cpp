// palp convert: any supported scan -> sparse, isotropic .vdb in world metres (LPS).
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <vector>

#include "batch_heap.h"
#include "commands.h"
#include "convert/convert_flags.h"
#include "palp/base/error.h"
#include "palp/volume/convert.h"
#include "progress.h"
#include "volume_flags.h"

namespace palp::tool {

namespace fs = std::filesystem;

Command addConvert(CLI::App& root) {
    struct Args {
        std::vector<std::string> inputs;
        std::string output;
        std::string series;
        ConvertFlags flags;
    };
    auto args = std::make_shared<Args>();
    CLI::App* app = root.add_subcommand(
        "convert",
        "Convert a DICOM series, NIfTI, NRRD, MetaImage or .vdb into a palp .vdb volume");
    app->add_option("inputs", args->inputs, "Input file(s) or a DICOM directory")->required();
    app->add_option("-o,--output", args->output, "Output .vdb file")->required();
    app->add_option("--series", args->series, "DICOM SeriesInstanceUID to convert");
    addConvertFlags(*app, args->flags);
    return {app, [args]() -> int {
                batchHeap();
                const fs::path out(args->output);
                const fs::path dir = out.has_parent_path() ? out.parent_path() : fs::path(".");
                std::error_code ec;
                if (!fs::is_directory(dir, ec)) {
                    throw IoError(out.string() + ": expected an existing directory '" +
                                  dir.string() + "' for the output, found none");
                }
                volume::LoadOptions opt = loadOptions(args->flags);
                if (!args->series.empty()) opt.seriesUid = args->series;
                opt.resample.progress = progressLine("palp convert: resampling");
                std::vector<fs::path> inputs(args->inputs.begin(), args->inputs.end());
                const volume::ConvertSummary vol = withVolumeFlags(
                    [&] { return volume::convert(inputs, out, opt, saveOptions(args->flags)); });
                endProgress();
                if (!globals().quiet) {
                    std::printf("palp convert: wrote %s: %s\n", out.c_str(),
                                describeVolume(vol).c_str());
                    // Every value the background threshold took away is counted (issue 37: MR
                    // field maps and phase images lost their negative values without a word).
                    std::printf("palp convert: %s\n", describeBackground(vol).c_str());
                }
                return 0;
            }};
}

}  // namespace palp::tool
