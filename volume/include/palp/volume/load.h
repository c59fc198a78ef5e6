#pragma once
/// @file
/// Loading scans of any supported format into a Volume, and saving Volumes as `.vdb`.

#include <filesystem>
#include <optional>
#include <string>
#include <vector>

#include "palp/volume/read_options.h"
#include "palp/volume/resample.h"
#include "palp/volume/volume.h"

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

/// Writes @p volume to @p path as a `.vdb` with its metadata, the grid named "scan".
/// @p volume is not changed (the file's name and metadata go on a grid sharing its tree and
/// transform). Writes through palp::AtomicFile, so a failure leaves no partial file.
/// @throw IoError naming the path when it cannot be written.
void save(const Volume& volume, const std::filesystem::path& path, const SaveOptions& options = {});

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

/// save(load(@p inputs, @p options), @p output, @p saveOptions): the same file but for its
/// random UUID. A source that is resampled (DICOM, NIfTI, NRRD, MetaImage) into a file with the
/// default compression never has its grid's values in memory: each leaf is packed as the file
/// stores it (its active values) when it is filled, and the file is written from those (the
/// head CT at 0.5 mm: 137 MB of packed values where the grid held 152 MiB of leaves, and no
/// pass over the grid to write it). Other sources and compressions go through load() and save().
/// @throw what load() and save() throw.
ConvertSummary convert(const std::vector<std::filesystem::path>& inputs,
                       const std::filesystem::path& output, const LoadOptions& options = {},
                       const SaveOptions& saveOptions = {});

/// Reads a palp `.vdb` (the grid named "scan", or the first float grid) as stored. The grid must
/// have a linear transform with cubic voxels, or an axis-aligned scale (native spacing), with
/// edges inside bounds::kSpacing and finite values (background and active) inside
/// bounds::kVolumeValue. load() of a `.vdb` re-grids non-cubic voxels to cubic ones
/// (resample(const Volume&)); loadVdb() does not.
/// @throw IoError, FormatError naming the file (and what in it is refused).
Volume loadVdb(const std::filesystem::path& path);

}  // namespace palp::volume
