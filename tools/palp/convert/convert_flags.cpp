#include "convert_flags.h"

#include <cmath>
#include <cstdio>
#include <string>

#include "../option_checks.h"
#include "palp/base/error.h"
#include "palp/base/validate.h"

namespace palp::tool {

void addConvertFlags(CLI::App& app, ConvertFlags& flags) {
    const CLI::Validator edge = within(bounds::kSpacing, kMm);
    app.add_option_function<std::string>(
           "--voxel-size",
           [&flags](const std::string& text) {
               flags.voxelNative = text == "native";
               flags.voxelMm = flags.voxelNative ? 0 : std::stod(text);
           },
           "Isotropic voxel edge in mm (default: finest input spacing), or native: the "
           "source's column x row x slice spacing (axis-aligned, evenly spaced slices only; "
           "others are refused)")
        ->check(CLI::Validator(
            [edge](std::string& text) -> std::string {
                if (text == "native") return {};
                std::string checked = text;
                std::string error = edge(checked);
                const std::size_t found = error.find(", found ");
                if (found != std::string::npos) error.insert(found, " or native");
                return error;
            },
            "MM or native"));
    app.add_option("--volume", flags.volume, "0-based time point of a 4D series or file")
        ->check(integerIn(0, 1000000));
    app.add_option("--background", flags.background,
                   "Values below this become inactive background (default -900 for CT, none "
                   "for MR, 0 otherwise); the values lost to it are counted")
        ->check(within(bounds::kVolumeValue));
    app.add_option("--crop", flags.cropMm, "World box in mm (LPS): xmin,ymin,zmin,xmax,ymax,zmax")
        ->delimiter(',')
        ->expected(6)
        ->check(within(bounds::kPosition, kMm));
    app.add_option("--compression", flags.compression,
                   "Leaf values: mask (default: active values as plain floats, inactive "
                   "dropped), blosc (LZ4: ~15 % smaller for CT, ~3x the write time) or zip "
                   "(~9 % smaller, ~20x the write time)")
        ->check(CLI::IsMember({"blosc", "zip", "mask"}));
}

volume::LoadOptions loadOptions(const ConvertFlags& flags) {
    volume::LoadOptions opt;
    if (flags.voxelMm > 0) opt.resample.voxelSize = flags.voxelMm * 1e-3;
    opt.resample.nativeSpacing = flags.voxelNative;
    if (flags.volume >= 0) opt.timePoint = flags.volume;
    if (!std::isnan(flags.background))
        opt.resample.backgroundThreshold = static_cast<float>(flags.background);
    if (!flags.cropMm.empty()) {
        const std::vector<double>& c = flags.cropMm;
        if (!(c[0] < c[3] && c[1] < c[4] && c[2] < c[5])) {
            throwExpected("--crop", "xmin < xmax, ymin < ymax and zmin < zmax (mm)",
                          formatValue(c[0]) + "," + formatValue(c[1]) + "," + formatValue(c[2]) +
                              "," + formatValue(c[3]) + "," + formatValue(c[4]) + "," +
                              formatValue(c[5]));
        }
        volume::WorldBox box;
        box.min = Eigen::Vector3d(c[0], c[1], c[2]) * 1e-3;
        box.max = Eigen::Vector3d(c[3], c[4], c[5]) * 1e-3;
        opt.resample.crop = box;
    }
    return opt;
}

volume::SaveOptions saveOptions(const ConvertFlags& flags) {
    volume::SaveOptions so;
    so.compression = flags.compression == "zip"    ? volume::Compression::Zip
                     : flags.compression == "mask" ? volume::Compression::ActiveMask
                                                   : volume::Compression::Blosc;
    return so;
}

namespace {
/// @p v with every digit a double holds (so that two runs' texts differ exactly when their
/// values do).
std::string exactNumber(double v) {
    char b[40];
    std::snprintf(b, sizeof b, "%.17g", v);
    return b;
}
}  // namespace

std::string describeConvertFlags(const ConvertFlags& flags) {
    std::string s = "voxel-size=";
    s += flags.voxelNative ? "native" : flags.voxelMm > 0 ? exactNumber(flags.voxelMm) : "default";
    s += " volume=";
    s += flags.volume >= 0 ? std::to_string(flags.volume) : "default";
    s += " background=";
    s += std::isnan(flags.background) ? "default" : exactNumber(flags.background);
    s += " crop=";
    if (flags.cropMm.empty()) {
        s += "none";
    } else {
        for (std::size_t i = 0; i < flags.cropMm.size(); ++i)
            s += (i ? "," : "") + exactNumber(flags.cropMm[i]);
    }
    s += " compression=" + flags.compression;
    return s;
}

std::string describeVolume(const volume::ConvertSummary& vol) {
    const auto& b = vol.worldBounds;
    const openvdb::Vec3d e = vol.voxelSizes * 1e3;
    char voxel[96];
    if (vol.hasCubicVoxels()) {
        std::snprintf(voxel, sizeof voxel, "%.4g", e[0]);
    } else {
        std::snprintf(voxel, sizeof voxel, "%.4g x %.4g x %.4g", e[0], e[1], e[2]);
    }
    // "DICOM CT", or "NIfTI-1" alone where the source does not say its modality.
    const std::string source = vol.info.modality.empty()
                                   ? vol.info.sourceFormat
                                   : vol.info.sourceFormat + " " + vol.info.modality;
    char line[600];
    std::snprintf(line, sizeof line,
                  "%s, voxel %s mm, %llu active voxels, world box (%.1f, %.1f, %.1f) - "
                  "(%.1f, %.1f, %.1f) mm",
                  source.c_str(), voxel, static_cast<unsigned long long>(vol.activeVoxels),
                  b.min().x() * 1e3, b.min().y() * 1e3, b.min().z() * 1e3, b.max().x() * 1e3,
                  b.max().y() * 1e3, b.max().z() * 1e3);
    return line;
}

std::string describeBackground(const volume::ConvertSummary& vol) {
    if (vol.info.backgroundThreshold <= volume::kNoBackgroundThreshold)
        return "no background threshold: no source value deactivated";
    char line[256];
    std::snprintf(line, sizeof line,
                  "background threshold %.6g: %llu source values below it now read as the "
                  "background %.6g",
                  static_cast<double>(vol.info.backgroundThreshold),
                  static_cast<unsigned long long>(vol.info.valuesBelowThreshold),
                  static_cast<double>(vol.background));
    return line;
}

}  // namespace palp::tool
