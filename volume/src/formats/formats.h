#pragma once
/// @file
/// Readers for single-file formats: NIfTI-1/2 (nifticlib), NRRD and MetaImage (palp's own
/// header parsers). Each returns one 3D volume as a SliceStack in world metres (LPS).
/// Internal (not installed): callers go through readStack() or load() in load.h.

#include <filesystem>
#include <string>
#include <string_view>

#include "lazy_stack.h"
#include "palp/volume/read_options.h"
#include "palp/volume/slice_stack.h"

namespace palp::volume {

/// NIfTI-1 or NIfTI-2 (.nii, .nii.gz, .hdr/.img). sform is used when its code is set, else
/// qform, else the pixdim scaling; RAS is converted to LPS; scl_slope/scl_inter applied.
SliceStack readNifti(const std::filesystem::path& path, const ReadOptions& options);

namespace detail {

/// readNifti() with the values decoded a slice at a time as the resampler reaches them
/// (raw_slices.h): every check of the header and of the file's size made here, before any
/// slice is decoded.
LazySliceStack openNifti(const std::filesystem::path& path, const ReadOptions& options);

/// readNrrd() decoded a slice at a time where the chosen volume is stored contiguously (raw
/// or gzip, the spatial axes first and in order, a time axis last); other layouts (ASCII data,
/// permuted axes, a time axis before the spatial ones) are read whole, as readNrrd().
LazySliceStack openNrrd(const std::filesystem::path& path, const ReadOptions& options);

/// readMetaImage() decoded a slice at a time (binary data; ASCII data is read whole).
LazySliceStack openMetaImage(const std::filesystem::path& path, const ReadOptions& options);

}  // namespace detail

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
