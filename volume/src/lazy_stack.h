#pragma once
/// @file
/// Internal to palp_volume (and its tests): a slice stack whose pixels are decoded as the
/// resampler reaches them, so that load() of a DICOM series never holds the whole series: its
/// peak is the output grid plus a band of slices along the normal.

#include <cstddef>
#include <filesystem>
#include <functional>
#include <vector>

#include "palp/volume/read_options.h"
#include "palp/volume/resample.h"
#include "palp/volume/slice_stack.h"

namespace palp::volume::detail {

class PackedLeaves;

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

/// resample() of @p lazy, the same grid as resample(SliceStack) of the decoded stack. Each slice
/// is decoded (in parallel, a band at a time) when the first block that reads it comes and
/// released when the last has passed; slices no block reads (outside a crop) are decoded and
/// checked at the end, so a damaged file is refused whatever the crop. Leaves @p lazy's values
/// released. With @p packed, the leaves go there instead (FillContext::packed) and the grid
/// has none.
/// @throw what decode throws (within a band, the lowest slice's error first); FormatError
///        naming the slice for a value checkStackValues() refuses; what resample() throws.
Volume resampleLazy(LazySliceStack& lazy, const ResampleOptions& options,
                    PackedLeaves* packed = nullptr);

/// Checks slice @p k of a stack as checkStackValues() does.
/// @throw ValueError as checkStackValues().
void checkSliceValues(const Slice& s, std::size_t k);

/// readDicom() without decoding the pixels of single-frame series (Siemens mosaics and
/// enhanced multi-frame files are decoded here, as readDicom() does): the same checks and
/// refusals before any pixel is decoded, the same slices, info and values once decoded.
LazySliceStack openDicom(const std::vector<std::filesystem::path>& inputs,
                         const ReadOptions& options);

}  // namespace palp::volume::detail
