// Re-gridding a stored volume: the `.vdb` counterpart of resample(SliceStack).
#include <openvdb/tools/GridTransformer.h>

#include <cmath>
#include <cstdint>
#include <memory>

#include "palp/base/bounds.h"
#include "palp/base/error.h"
#include "palp/base/validate.h"
#include "palp/volume/resample.h"
#include "resample/grid_copy.h"
#include "vdb/vdb_errors.h"

namespace palp::volume {

namespace {

/// Makes active values below @p threshold, or equal to the background, inactive; returns how
/// many below the threshold were not the background (values the grid no longer holds).
std::uint64_t deactivateBelow(openvdb::FloatGrid& grid, float threshold) {
    const float background = grid.background();
    std::uint64_t lost = 0;
    for (auto it = grid.beginValueOn(); it; ++it) {
        if (*it < threshold || *it == background) {
            lost += *it == background ? 0u : 1u;
            it.setValueOff();
        }
    }
    return lost;
}

Volume regridChecked(const Volume& source, const ResampleOptions& options) {
    const bool toCubic = !source.hasCubicVoxels() && !options.nativeSpacing;
    const bool regrid = options.voxelSize || options.crop || toCubic;
    if (!regrid && !options.backgroundThreshold) return source;
    openvdb::FloatGrid::Ptr target;
    if (regrid) {
        // Trilinear resample onto the requested lattice (a native one keeps its transform).
        target = openvdb::FloatGrid::create(source.grid->background());
        target->setName(kScanGridName);
        if (options.nativeSpacing) {
            target->setTransform(source.grid->transform().copy());
        } else {
            const double voxel = options.voxelSize.value_or(source.voxelSize());
            palp::requireWithin("resample: voxel size", voxel, bounds::kSpacing, {1e3, "mm"});
            target->setTransform(openvdb::math::Transform::createLinearTransform(voxel));
        }
        openvdb::tools::resampleToMatch<openvdb::tools::BoxSampler>(*source.grid, *target);
        if (options.crop) {
            target->clipGrid(openvdb::BBoxd(openvdb::Vec3d(options.crop->min.data()),
                                            openvdb::Vec3d(options.crop->max.data())));
        }
    } else {
        target = detail::gridWithTree(*source.grid,
                                      std::make_shared<openvdb::FloatTree>(source.grid->tree()));
    }
    Volume out{target, source.info};
    if (options.backgroundThreshold) {
        out.info.valuesBelowThreshold += deactivateBelow(*target, *options.backgroundThreshold);
        out.info.backgroundThreshold = *options.backgroundThreshold;
    }
    writeInfo(out.info, *target);
    if (options.progress && !options.progress(1.0)) throw Error("resample: cancelled");
    return out;
}

}  // namespace

Volume resample(const Volume& source, const ResampleOptions& options) {
    if (!source.grid) throwExpected("resample", "a volume with a grid", "none");
    checkResampleOptions(options);
    return detail::withVdbErrors<ValueError>("resample", "a grid OpenVDB can re-grid",
                                             [&] { return regridChecked(source, options); });
}

}  // namespace palp::volume
