#pragma once
/// @file
/// Loading scans of any supported format into a Volume, and saving Volumes as `.vdb` (with
/// convert.h: formats, options, readStack() and convert()).

#include <filesystem>
#include <optional>
#include <string>
#include <vector>

#include "palp/volume/convert.h"
#include "palp/volume/read_options.h"
#include "palp/volume/resample.h"
#include "palp/volume/volume.h"

namespace palp::volume {

/// Reads and resamples @p inputs into a Volume: slices through resample(SliceStack), a `.vdb`
/// through resample(Volume) with the same options (as stored unless a voxel size, crop or
/// background threshold is given). A single-frame DICOM series is never held whole: each slice
/// is decoded when the resampler first needs it and released once it has passed (a band of
/// slices along the normal at a time), so the peak memory is about the output grid plus that
/// band; the grid is the one readStack() then resample() gives.
/// @p options.resample is checked first (checkResampleOptions()). OpenVDB's own exceptions come
/// out as FormatError naming the file.
/// @throw IoError, FormatError, ValueError with the offending file or option named.
Volume load(const std::vector<std::filesystem::path>& inputs, const LoadOptions& options = {});

/// Writes @p volume to @p path as a `.vdb` with its metadata, the grid named "scan".
/// @p volume is not changed (the file's name and metadata go on a grid sharing its tree and
/// transform). Writes through palp::AtomicFile, so a failure leaves no partial file.
/// @throw IoError naming the path when it cannot be written.
void save(const Volume& volume, const std::filesystem::path& path, const SaveOptions& options = {});

/// Reads a palp `.vdb` (the grid named "scan", or the first float grid) as stored. The grid must
/// have a linear transform with cubic voxels, or an axis-aligned scale (native spacing), with
/// edges inside bounds::kSpacing and finite values (background and active) inside
/// bounds::kVolumeValue. load() of a `.vdb` re-grids non-cubic voxels to cubic ones
/// (resample(const Volume&)); loadVdb() does not.
/// @throw IoError, FormatError naming the file (and what in it is refused).
Volume loadVdb(const std::filesystem::path& path);

}  // namespace palp::volume
