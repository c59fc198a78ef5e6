#pragma once
// Scanning DICOM inputs (internal): a cheap header scan of every file (gdcm::Scanner), the
// grouping of files into series, and the choice of one series.
#include <cstddef>
#include <filesystem>
#include <string>
#include <utility>
#include <vector>

#include "dicom/dicom_header.h"
#include "dicom/dicom_walk.h"
#include "palp/volume/dicom.h"
#include "palp/volume/find_scans.h"

namespace palp::volume::dicom {

struct Scan {
    std::string inputsName;  // for messages: the input directory or file(s)
    std::size_t fileCount = 0;
    std::vector<Header> headers;                                  // DICOM files only
    std::vector<std::pair<std::filesystem::path, Walk>> damaged;  // DICOM files GDCM must not see
    // Complete DICOM Part 10 files whose data set GDCM could not parse (an unknown transfer
    // syntax, most often).
    std::vector<std::pair<std::filesystem::path, Walk>> unparsed;
};

/// Refuses a series that holds a file in a transfer syntax GDCM does not know, naming it.
/// @throw FormatError naming the file and the syntax.
void checkTransferSyntax(const Header& h);

/// Scans the headers of every file in @p inputs (directories recursively); damaged files are
/// set aside in Scan::damaged, files that are not DICOM are skipped.
/// @throw IoError when an input does not exist or a directory cannot be read.
Scan scanHeaders(const std::vector<std::filesystem::path>& inputs);

/// @throw FormatError saying that @p scan found no DICOM file.
[[noreturn]] void throwNoDicom(const Scan& scan);

/// The series of a scan, in the order of DicomSeriesInfo (description, then UID).
struct SeriesGroup {
    std::string uid;
    std::vector<const Header*> files;   // all files of the series
    std::vector<const Header*> images;  // those with Rows and Columns
};

/// The series of @p scan, sorted by description, then UID.
std::vector<SeriesGroup> groupSeries(const Scan& scan);

/// What scanDicom reports for one series.
DicomSeriesInfo describeSeries(const SeriesGroup& g);

/// The series to read: options.seriesUid, or the only series with images.
/// @throw ValueError (unknown UID, several series without a choice), FormatError (no images).
const SeriesGroup& chooseSeries(const Scan& scan, const std::vector<SeriesGroup>& groups,
                                const ReadOptions& options);

/// The inputs and the series description, for messages.
std::string seriesName(const Scan& scan, const SeriesGroup& g);

/// The DICOM series of @p files (find_scans' DICOM part), with their damaged and unparsable
/// files placed as FoundScan::files says.
std::vector<FoundScan> findScans(const std::vector<std::filesystem::path>& files);

}  // namespace palp::volume::dicom
