#pragma once
/// @file
/// ReadOptions: what the scan readers (DICOM, NIfTI, NRRD, MetaImage) need to know to read one
/// 3D volume as slices: which series, which time point, and how much memory it may take.

#include <cstdint>
#include <optional>
#include <string>

namespace palp::volume {

/// Choices and limits for reading one 3D volume of a scan as a SliceStack.
struct ReadOptions {
    /// DICOM: SeriesInstanceUID to read when the inputs hold several series.
    std::optional<std::string> seriesUid;
    /// 4D sources: 0-based index of the time point (volume) to read. Required when the source
    /// holds more than one time point; a source with one accepts none or 0.
    std::optional<int> timePoint;
    /// Largest decoded source size accepted, in bytes; headers claiming more are refused before
    /// any allocation.
    std::uint64_t maxSourceBytes = std::uint64_t{8} << 30;
};

}  // namespace palp::volume
