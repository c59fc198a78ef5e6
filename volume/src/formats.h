#pragma once
/// @file
/// Readers for single-file formats: NIfTI-1/2 (nifticlib), NRRD and MetaImage (palp's own
/// header parsers). Each returns one 3D volume as a SliceStack in world metres (LPS).
/// Internal (not installed): callers go through readStack() or load() in load.h.

#include <filesystem>
#include <string>
#include <string_view>

#include "palp/volume/read_options.h"
#include "palp/volume/slice_stack.h"

namespace palp::volume {

/// NIfTI-1 or NIfTI-2 (.nii, .nii.gz, .hdr/.img). sform is used when its code is set, else
/// qform, else the pixdim scaling; RAS is converted to LPS; scl_slope/scl_inter applied.
SliceStack readNifti(const std::filesystem::path& path, const ReadOptions& options);

/// What @p path's content says it is, whatever its name: "a NIfTI-1 file", "a gzip-compressed
/// NIfTI-2 file", "a DICOM file", "an NRRD file", "a MetaImage header", "an OpenVDB file", "a
/// gzip stream"; empty when its first bytes match none of them (or it cannot be read).
std::string describeContent(const std::filesystem::path& path);

/// Whether @p path is named as nifticlib expects a NIfTI file (.nii, .nii.gz, .hdr, .img,
/// .hdr.gz, .img.gz; any case).
bool hasNiftiName(const std::filesystem::path& path);

/// NRRD (.nrrd attached or .nhdr detached; raw or gzip; space directions and origin).
SliceStack readNrrd(const std::filesystem::path& path, const ReadOptions& options);

/// MetaImage (.mha or .mhd with raw data file; zlib-compressed or not).
SliceStack readMetaImage(const std::filesystem::path& path, const ReadOptions& options);

}  // namespace palp::volume
