#include "palp/volume/volume.h"

#include <algorithm>
#include <mutex>
#include <type_traits>

#include "volume_info_fields.h"

namespace palp::volume {

namespace {

template <typename T>
T metaOr(const openvdb::GridBase& grid, const char* key, T fallback) {
    if (auto m = grid.getMetadata<openvdb::TypedMetadata<T>>(key)) return m->value();
    return fallback;
}

}  // namespace

void initialize() {
    static std::once_flag once;
    std::call_once(once, [] { openvdb::initialize(); });
}

openvdb::BBoxd Volume::worldBounds() const {
    const openvdb::CoordBBox box = grid->evalActiveVoxelBoundingBox();
    if (box.empty()) return openvdb::BBoxd();
    return grid->transform().indexToWorld(box);
}

void writeInfo(const VolumeInfo& info, openvdb::GridBase& grid) {
    detail::forEachInfoField(info, [&](const char* name, const auto& value) {
        using T = std::decay_t<decltype(value)>;
        if constexpr (std::is_same_v<T, std::array<std::int32_t, 3>>) {
            grid.insertMeta(name,
                            openvdb::Vec3IMetadata(openvdb::Vec3i(value[0], value[1], value[2])));
        } else if constexpr (std::is_same_v<T, std::array<double, 3>>) {
            grid.insertMeta(name,
                            openvdb::Vec3DMetadata(openvdb::Vec3d(value[0], value[1], value[2])));
        } else {
            grid.insertMeta(name, openvdb::TypedMetadata<T>(value));
        }
    });
}

VolumeInfo readInfo(const openvdb::GridBase& grid) {
    VolumeInfo info;
    info.modality = metaOr<std::string>(grid, "palp:modality", "");
    info.valueUnits = metaOr<std::string>(grid, "palp:value_units", "");
    info.sourceFormat = metaOr<std::string>(grid, "palp:source_format", "");
    info.sourceDescription = metaOr<std::string>(grid, "palp:source_description", "");
    info.seriesUid = metaOr<std::string>(grid, "palp:series_uid", "");
    const openvdb::Vec3i dims = metaOr(grid, "palp:original_dims", openvdb::Vec3i(0, 0, 0));
    info.originalDims = {dims[0], dims[1], dims[2]};
    const openvdb::Vec3d sp = metaOr(grid, "palp:original_spacing_m", openvdb::Vec3d(0, 0, 0));
    info.originalSpacing = {sp[0], sp[1], sp[2]};
    info.minSliceGap = metaOr(grid, "palp:min_slice_gap_m", 0.0);
    info.maxSliceGap = metaOr(grid, "palp:max_slice_gap_m", 0.0);
    info.rescaleSlope = metaOr(grid, "palp:rescale_slope", 1.0);
    info.rescaleIntercept = metaOr(grid, "palp:rescale_intercept", 0.0);
    info.gantryTiltDeg = metaOr(grid, "palp:gantry_tilt_deg", 0.0);
    info.timePoint = metaOr(grid, "palp:time_point", -1);
    info.timePointCount = metaOr(grid, "palp:time_point_count", 1);
    info.phaseEncodingPolarityGE = metaOr<std::string>(grid, "palp:phase_encoding_polarity_ge", "");
    info.backgroundThreshold = metaOr(grid, "palp:background_threshold", -900.0f);
    info.valuesBelowThreshold = static_cast<std::uint64_t>(
        std::max<std::int64_t>(0, metaOr(grid, "palp:values_below_threshold", std::int64_t{0})));
    return info;
}

}  // namespace palp::volume
