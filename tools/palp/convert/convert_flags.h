#pragma once
/// @file
/// The volume flags `palp convert` and `palp convert-tree` share (--voxel-size, --volume,
/// --background, --crop, --compression): registered once, turned into the volume library's
/// options once, so one series converts alike through either command.

#include <CLI/CLI.hpp>
#include <limits>
#include <string>
#include <vector>

#include "palp/volume/convert.h"

namespace palp::tool {

/// The shared flags as the user gave them (0, -1, NaN or empty: not given).
struct ConvertFlags {
    double voxelMm = 0;
    bool voxelNative = false;  ///< --voxel-size native
    int volume = -1;
    double background = std::numeric_limits<double>::quiet_NaN();
    std::vector<double> cropMm;
    std::string compression = "mask";
};

/// Registers the shared flags on @p app, writing into @p flags (which must outlive parsing).
void addConvertFlags(CLI::App& app, ConvertFlags& flags);

/// The load options the flags ask for (series and progress left unset).
/// @throw ValueError naming --crop when its corners are not min < max.
volume::LoadOptions loadOptions(const ConvertFlags& flags);

/// The save options the flags ask for.
volume::SaveOptions saveOptions(const ConvertFlags& flags);

/// The flags as one line of text, every value exact ("voxel-size=0.5 (or native) volume=default
/// background=default crop=none compression=mask"): what a manifest records so that a resumed
/// run can tell whether it converts alike.
std::string describeConvertFlags(const ConvertFlags& flags);

/// A converted volume in words: "DICOM CT, voxel 0.5 mm, 1234 active voxels, world box (x, y,
/// z) - (x, y, z) mm" ("voxel 0.5 x 0.5 x 1 mm" for native spacing's non-cubic voxels).
std::string describeVolume(const volume::ConvertSummary& vol);

/// What the background threshold took away, in words: "no background threshold: no source
/// value deactivated", or the threshold, the count of source values below it and the
/// background they now read as (issue 37: nothing is lost without a word).
std::string describeBackground(const volume::ConvertSummary& vol);

}  // namespace palp::tool
