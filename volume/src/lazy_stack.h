#pragma once
/// @file
/// Internal to palp_volume_core (and palp_volume, and their tests): a slice stack whose pixels are
/// decoded as the resampler reaches them, so that load() of a DICOM series never holds the whole
/// series: its peak is the output grid plus a band of slices along the normal.

#include <cstddef>
#include <filesystem>
#include <functional>
#include <optional>
#include <vector>

#include "palp/volume/read_options.h"
#include "palp/volume/resample_options.h"
#include "palp/volume/slice_stack.h"

namespace palp::volume::detail {

struct LazySliceStack {
    /// The slices with their geometry, size (cols, rows) and source; values empty while
    /// @ref decode is set.
    SliceStack stack;
    /// Decodes slice @p index (stack order) into @p slice's values (cols x rows of them, as
    /// @ref stack says); returns true when the values are known to pass checkSliceValues()
    /// without looking at them (integer pixels with a moderate rescale), false when they must
    /// be checked. Called from several threads at once, for distinct slices. Empty when the
    /// values are already there.
    std::function<bool(std::size_t index, Slice& slice)> decode;
};

/// @throw IoError "<p>: expected an existing file or directory, found nothing".
void requireExists(const std::filesystem::path& p);

/// The stack of @p inputs read lazily: a DICOM series (openDicom()), or one NIfTI, NRRD or
/// MetaImage file (formats.h); std::nullopt for anything else (a `.vdb`, a file of unknown
/// format, several files that are not DICOM), which readStack() refuses or load() re-grids.
/// @throw what the readers' open functions throw.
std::optional<LazySliceStack> openLazy(const std::vector<std::filesystem::path>& inputs,
                                       const ReadOptions& options);

/// Checks @p lazy's values when they are there already (no decode) as readStack() does.
/// @throw FormatError naming the slice (the file is at fault).
void checkLazyValues(const LazySliceStack& lazy);

/// Checks slice @p k of a stack as checkStackValues() does.
/// @throw ValueError as checkStackValues().
void checkSliceValues(const Slice& s, std::size_t k);

/// readDicom() without decoding the pixels of single-frame series (Siemens mosaics and
/// enhanced multi-frame files are decoded here, as readDicom() does): the same checks and
/// refusals before any pixel is decoded, the same slices, info and values once decoded.
LazySliceStack openDicom(const std::vector<std::filesystem::path>& inputs,
                         const ReadOptions& options);

}  // namespace palp::volume::detail
