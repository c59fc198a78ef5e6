#pragma once
/// @file
/// Reading scans and converting them to `.vdb` files: formats, load options, readStack() and
/// convert(). Free of OpenVDB's library (palp_volume_core): `palp convert` of a DICOM, NIfTI,
/// NRRD or MetaImage source never loads it. load(), save() and loadVdb() are in load.h.

#include <openvdb/Types.h>

#include <cstdint>
#include <filesystem>
#include <string>
#include <vector>

#include "palp/volume/read_options.h"
#include "palp/volume/resample_options.h"
#include "palp/volume/slice_stack.h"
#include "palp/volume/volume_info.h"

namespace palp::volume {

/// Input formats palp recognises.
enum class Format { Unknown, Dicom, Nifti, Nrrd, MetaImage, Vdb };

/// Human-readable format name.
const char* formatName(Format f);

/// Detects a file's format from its magic bytes, falling back to its extension. A directory is
/// DICOM. Does not throw for unreadable files (returns Unknown).
Format detectFormat(const std::filesystem::path& path);

/// What load() needs: the readers' choices and limits (series, time point, memory) plus how the
/// slices become a grid.
struct LoadOptions : ReadOptions {
    /// How the slices become a grid (voxel size, background, crop, progress). Also applied to a
    /// `.vdb` input when it is re-gridded.
    ResampleOptions resample;
};

/// Reads @p inputs (one file, one directory, or several DICOM files of one series) as a
/// SliceStack without resampling. Not for `.vdb` (use load()). A spacing, direction or origin
/// the file gives is used or refused (never replaced by a default); NaN or infinite voxels, or
/// values outside bounds::kVolumeValue, are refused.
/// @throw IoError, FormatError, ValueError with the offending file (and field) named.
SliceStack readStack(const std::vector<std::filesystem::path>& inputs, const ReadOptions& options);

/// How `.vdb` leaf data is stored on disk. Every mode drops inactive values (OpenVDB's
/// active-mask compression); ActiveMask (the default) stores the active values as plain 32-bit
/// floats, as dcm2niix's default `.nii` stores its values uncompressed. Blosc (LZ4) gives ~15 %
/// smaller files for CT at ~2.8x the write CPU time (the head CT at 0.5 mm: 116 against 137 MB,
/// 0.59 against 0.20 s, bench/volume/bench_convert), Zip ~9 % smaller (125 MB) at ~20x.
/// Reading is as fast for ActiveMask as for Blosc.
enum class Compression { ActiveMask, Blosc, Zip };

struct SaveOptions {
    Compression compression = Compression::ActiveMask;
};

/// What convert() wrote, without the values: the volume's metadata, its active voxels and their
/// world box (metres, of the voxel centres; empty for an empty grid), the voxel's edges
/// (metres) and the background value.
struct ConvertSummary {
    VolumeInfo info;
    std::uint64_t activeVoxels = 0;
    openvdb::BBoxd worldBounds;
    openvdb::Vec3d voxelSizes{0, 0, 0};
    float background = 0;

    /// Whether the voxels are cubic (the three edges equal, bit for bit).
    bool hasCubicVoxels() const {
        return voxelSizes[0] == voxelSizes[1] && voxelSizes[1] == voxelSizes[2];
    }
};

/// save(load(@p inputs, @p options), @p output, @p saveOptions) (load.h): the same file but for
/// its random UUID. A source that is resampled (DICOM, NIfTI, NRRD, MetaImage) into a file with
/// the default compression never has its grid's values in memory: each leaf is packed as the
/// file stores it (its active values) when it is filled, and the file is written from those
/// (the head CT at 0.5 mm: 137 MB of packed values where the grid held 152 MiB of leaves, and
/// no pass over the grid to write it), without OpenVDB's library. Other sources and
/// compressions go through load() and save() of libpalp_volume, which convert() opens (beside
/// libpalp_volume_core, as loaded) unless it is loaded already.
/// @throw what load() and save() throw; IoError naming libpalp_volume when it cannot be opened.
ConvertSummary convert(const std::vector<std::filesystem::path>& inputs,
                       const std::filesystem::path& output, const LoadOptions& options = {},
                       const SaveOptions& saveOptions = {});

/// convert() as load() then save(), which libpalp_volume exports for palp_volume_core's
/// convert(): the symbol kLoadAndSaveEntry (dlsym) is an `extern "C"` function taking nothing
/// and returning it.
using ConvertFn = ConvertSummary (*)(const std::vector<std::filesystem::path>& inputs,
                                     const std::filesystem::path& output,
                                     const LoadOptions& options, const SaveOptions& saveOptions);
inline constexpr const char* kLoadAndSaveEntry = "palp_volume_load_and_save";

}  // namespace palp::volume
