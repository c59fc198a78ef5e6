#pragma once
/// @file
/// VolumeInfo: the non-identifying acquisition facts a volume carries, and the name of the grid
/// a palp `.vdb` stores. Free of OpenVDB, so palp_volume_core's readers and converter use it
/// without OpenVDB's library.

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

}  // namespace palp::volume
