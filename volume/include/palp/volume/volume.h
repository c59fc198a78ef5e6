#pragma once
/// @file
/// Volume: a scan as a sparse OpenVDB grid with a world transform and non-identifying metadata.

#include <openvdb/openvdb.h>

#include <algorithm>
#include <array>
#include <cstdint>
#include <string>

namespace palp::volume {

/// Name of the grid that holds scan values in every palp `.vdb` file.
inline constexpr const char* kScanGridName = "scan";

/// Acquisition facts carried with a volume. Nothing here identifies a patient: palp copies no
/// patient, physician, institution, date or accession tags.
struct VolumeInfo {
    std::string modality;    ///< DICOM modality ("CT", "MR", ...) or "" when unknown
    std::string valueUnits;  ///< "HU" for CT, otherwise "" (scanner intensity)
    std::string
        sourceFormat;  ///< "DICOM", "NIfTI-1", "NIfTI-2", "NRRD", "MetaImage", "VDB", "phantom"
    std::string sourceDescription;  ///< series description or file name, free text
    std::string seriesUid;          ///< DICOM SeriesInstanceUID (empty for other formats)
    std::array<std::int64_t, 3> originalDims{0, 0, 0};  ///< columns, rows, slices of the source
    std::array<double, 3> originalSpacing{0, 0,
                                          0};  ///< metres: column step, row step, median slice gap
    double minSliceGap = 0;       ///< metres, smallest gap between adjacent slices along the normal
    double maxSliceGap = 0;       ///< metres, largest gap (differs from min for uneven spacing)
    double rescaleSlope = 1;      ///< applied to stored values (value = slope * stored + intercept)
    double rescaleIntercept = 0;  ///< see rescaleSlope
    double gantryTiltDeg = 0;     ///< angle between the slice normal and the stacking direction
    int timePoint = -1;           ///< 0-based volume index chosen from a 4D source, -1 for 3D
    int timePointCount = 1;       ///< number of volumes in the source
    /// GE EPI phase-encoding polarity, "Flipped" or "Unflipped" as dcm2niix's JSON sidecar
    /// writes PhaseEncodingPolarityGE; "" when not a GE EPI or not told. Recorded only: neither
    /// palp nor dcm2niix changes a pixel for it (docs/volumes.md).
    std::string phaseEncodingPolarityGE;
    float backgroundThreshold = -900;  ///< values below this became inactive background
    /// Source values (pixels of the slices read) below backgroundThreshold, other than the
    /// background value itself: values the grid no longer holds (they read as the background).
    /// Counted by resample() of slices; 0 for volumes made otherwise.
    std::uint64_t valuesBelowThreshold = 0;
};

/// A scan as a sparse grid. `grid` is named "scan"; its transform maps index space to world
/// metres in the DICOM patient frame (LPS: +x left, +y posterior, +z superior). Voxels are
/// axis-aligned (a scale and translation) and cubic, except for a grid made with native spacing
/// (ResampleOptions::nativeSpacing), whose voxels may have a different edge along each axis;
/// load() re-grids such a grid to cubic voxels unless asked to keep it, so the kernels, the
/// mesher and the haptics only ever see cubic voxels. Inactive voxels hold the grid's
/// background value (e.g. -1000 HU of air); active voxels hold values in `info.valueUnits`.
///
/// @par Threading  Read-only use from many threads is safe if each thread has its own accessor.
struct Volume {
    openvdb::FloatGrid::Ptr grid;
    VolumeInfo info;

    /// Edge length of a cubic voxel in metres; for non-cubic voxels, the smallest edge.
    double voxelSize() const {
        const openvdb::Vec3d v = grid->transform().voxelSize();
        return std::min(v[0], std::min(v[1], v[2]));
    }
    /// Edge lengths of a voxel along index x, y, z in metres.
    openvdb::Vec3d voxelSizes() const { return grid->transform().voxelSize(); }
    /// Whether the voxels are cubic (the three edges equal, bit for bit).
    bool hasCubicVoxels() const {
        const openvdb::Vec3d v = grid->transform().voxelSize();
        return v[0] == v[1] && v[1] == v[2];
    }
    /// World box (metres) of the active voxels' centres; empty box for an empty grid.
    openvdb::BBoxd worldBounds() const;
};

/// Writes @p info into @p grid's metadata (keys prefixed "palp:").
void writeInfo(const VolumeInfo& info, openvdb::GridBase& grid);
/// Reads what writeInfo wrote; missing keys keep their defaults.
VolumeInfo readInfo(const openvdb::GridBase& grid);

/// Initialises OpenVDB once (thread-safe, idempotent). Every palp entry point that touches
/// OpenVDB calls it; applications may call it early.
void initialize();

}  // namespace palp::volume
