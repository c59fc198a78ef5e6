#pragma once
/// @file
/// Internal to palp_volume: the grid metadata a VolumeInfo is stored as, each field named once,
/// for writeInfo() (OpenVDB's metadata) and the packed writer (the bytes OpenVDB writes for it).

#include <array>
#include <cstdint>
#include <string>

#include "palp/volume/volume_info.h"

namespace palp::volume::detail {

/// Calls @p put(name, value) for each field of @p info as a `.vdb` stores it. A value is a
/// std::string, std::array<std::int32_t, 3> (OpenVDB's vec3i), std::array<double, 3> (vec3d),
/// double, std::int32_t, float or std::int64_t.
template <typename Put>
void forEachInfoField(const VolumeInfo& info, Put&& put) {
    put("palp:modality", info.modality);
    put("palp:value_units", info.valueUnits);
    put("palp:source_format", info.sourceFormat);
    put("palp:source_description", info.sourceDescription);
    put("palp:series_uid", info.seriesUid);
    put("palp:original_dims",
        std::array<std::int32_t, 3>{static_cast<std::int32_t>(info.originalDims[0]),
                                    static_cast<std::int32_t>(info.originalDims[1]),
                                    static_cast<std::int32_t>(info.originalDims[2])});
    put("palp:original_spacing_m", info.originalSpacing);
    put("palp:min_slice_gap_m", info.minSliceGap);
    put("palp:max_slice_gap_m", info.maxSliceGap);
    put("palp:rescale_slope", info.rescaleSlope);
    put("palp:rescale_intercept", info.rescaleIntercept);
    put("palp:gantry_tilt_deg", info.gantryTiltDeg);
    put("palp:time_point", static_cast<std::int32_t>(info.timePoint));
    put("palp:time_point_count", static_cast<std::int32_t>(info.timePointCount));
    if (!info.phaseEncodingPolarityGE.empty())
        put("palp:phase_encoding_polarity_ge", info.phaseEncodingPolarityGE);
    put("palp:background_threshold", info.backgroundThreshold);
    put("palp:values_below_threshold", static_cast<std::int64_t>(info.valuesBelowThreshold));
}

}  // namespace palp::volume::detail
