#pragma once
/// @file
/// DICOM series reading (through GDCM) and writing (for phantoms).

#include <filesystem>
#include <string>
#include <vector>

#include "palp/volume/read_options.h"
#include "palp/volume/slice_stack.h"

namespace palp::volume {

/// One series found among DICOM files.
struct DicomSeriesInfo {
    std::string uid;          ///< SeriesInstanceUID
    std::string description;  ///< SeriesDescription (may be empty)
    std::string modality;     ///< Modality
    int imageCount = 0;       ///< files with pixel data in the series
    int frameCount = 0;       ///< frames in those files (a single-frame file counts one)
    int positionCount = 0;    ///< distinct slice positions (of frames, or of mosaic slices)
    int timePointCount = 1;   ///< frames per position when positions repeat (as readDicom)
    /// Why readDicom would refuse the frames of enhanced multi-frame files (their size,
    /// orientation, spacing, duplicates, missing time points); empty when they group cleanly
    /// and for single-frame series (which are checked only when read).
    std::string problem;
    std::vector<std::filesystem::path> files;
};

/// Lists the series in @p inputs (directories are searched recursively; files that are not
/// DICOM are skipped). Sorted by description, then UID.
/// @throw IoError when an input does not exist; FormatError when no DICOM file is found.
std::vector<DicomSeriesInfo> scanDicom(const std::vector<std::filesystem::path>& inputs);

/// Reads one 3D volume of a DICOM series as slices sorted along the slice normal, with the
/// rescale applied and each slice's own position, orientation and spacing.
/// Series choice: options.seriesUid, or the only series present (several without a choice are
/// refused, listing each with description and image count). 4D series (repeated positions)
/// need options.timePoint (0-based), or are refused with the number of time points.
/// Enhanced multi-frame files are read frame by frame (per-frame functional groups), also when
/// a series is split over several of them (one per time point, or the slices of a volume over
/// several files): their frames are grouped by position and time point like single-frame images.
/// @throw IoError, FormatError, ValueError naming the file.
SliceStack readDicom(const std::vector<std::filesystem::path>& inputs, const ReadOptions& options);

/// How writeDicomSeries stores values.
struct DicomWriteOptions {
    std::string modality = "CT";
    std::string seriesDescription = "palp phantom";
    double rescaleSlope = 1.0;        ///< stored = (value - intercept) / slope, rounded
    double rescaleIntercept = -1024;  ///< CT convention: unsigned storage, -1024 intercept
    double gantryTiltDeg = 0;         ///< written to (0018,1120) when non-zero
    /// Clamp finite values outside the storage range (like a scanner's -1024 HU floor) instead
    /// of refusing them; non-finite values are always refused.
    bool clampToStorage = false;
};

/// Writes @p stack as one single-frame CT/MR image per slice (uint16 storage) into @p dir,
/// which is created (an existing directory must be empty); files IMG0001.dcm... are written to
/// temporary names and renamed, and a failure removes what was written. Each file carries
/// fresh Study/Series/SOP Instance UIDs, the slice's geometry (ImagePositionPatient,
/// ImageOrientationPatient, PixelSpacing in mm), SliceThickness (the distance to the
/// neighbouring slice along the normal), InstanceNumber and the dummy patient PALP^PHANTOM.
/// @throw IoError, ValueError (values that do not fit the storage after rescale, checked before
///        anything is written; the message names the slice and the value).
void writeDicomSeries(const SliceStack& stack, const std::filesystem::path& dir,
                      const DicomWriteOptions& options = {});

}  // namespace palp::volume
