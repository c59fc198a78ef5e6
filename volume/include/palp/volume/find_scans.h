#pragma once
/// @file
/// Finding every scan under a folder: the DICOM series (grouped as the DICOM reader groups
/// them) and the NIfTI, NRRD and MetaImage files, each as the inputs load() takes to read it
/// alone. What `palp convert-tree` converts.

#include <filesystem>
#include <string>
#include <vector>

#include "palp/volume/convert.h"

namespace palp::volume {

/// One scan found by findScans(): one DICOM series or one NIfTI, NRRD or MetaImage file.
struct FoundScan {
    Format format = Format::Unknown;  ///< Dicom, Nifti, Nrrd or MetaImage
    /// DICOM: SeriesInstanceUID (empty for a series whose files carry none, and for files
    /// whose series could not be read); other formats: empty.
    std::string seriesUid;
    std::string description;  ///< DICOM SeriesDescription (may be empty); others: empty
    std::string modality;     ///< DICOM Modality; others: empty
    /// DICOM: files with Rows and Columns in the series (0: a series of non-image objects,
    /// such as structured reports, or a group of unreadable files); others: 1.
    int imageCount = 0;
    /// What load() reads, with seriesUid as LoadOptions::seriesUid for DICOM. A DICOM series'
    /// files, sorted, with the damaged or unparsable DICOM files that belong to it: those of
    /// its UID, and those whose UID cannot be read lying in a folder with one of its files (so
    /// load() refuses the series, naming the file, as it refuses the folder). Damaged or
    /// unparsable files that belong to no series are scans of their own (grouped by UID, or
    /// by folder when the UID cannot be read), which load() refuses with the reason.
    std::vector<std::filesystem::path> files;
    /// The deepest folder that holds every file (a file's own folder for the other formats).
    std::filesystem::path folder;
    /// No file of the scan is readable (damaged or unparsable DICOM files only).
    bool unreadable = false;
};

/// Every scan under @p root (searched recursively, directory symlinks not followed, folders
/// that cannot be read skipped), except under the folders in @p skip (an output folder inside
/// @p root, say). DICOM Part 10 files (`DICM` at byte 128) are grouped by SeriesInstanceUID
/// across all folders, as readDicom() groups its inputs; NIfTI (.nii, .nii.gz, .hdr), NRRD
/// and MetaImage files are recognised by content, then name (detectFormat()). OpenVDB files
/// and everything else are left out. Sorted by folder, then UID or file name.
/// Memory: the header scan keeps about 1 KB per DICOM file until it returns.
/// @throw IoError naming @p root when it is not a readable directory.
std::vector<FoundScan> findScans(const std::filesystem::path& root,
                                 const std::vector<std::filesystem::path>& skip = {});

}  // namespace palp::volume
