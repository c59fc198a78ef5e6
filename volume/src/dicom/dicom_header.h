#pragma once
// DICOM header values as palp reads them (internal): the tags scanned from every file, text and
// number parsing of their values, one file's scanned values (Header), and a file's checked
// geometry.
#include <gdcmTag.h>

#include <Eigen/Core>
#include <filesystem>
#include <map>
#include <optional>
#include <string>
#include <vector>

namespace palp::volume::dicom {

// Tags read from every file. No patient-identifying tag is read.
inline const gdcm::Tag kTransferSyntax(0x0002, 0x0010);  // from the file meta (structural walk)
inline const gdcm::Tag kImageType(0x0008, 0x0008);
inline const gdcm::Tag kSopClassUid(0x0008, 0x0016);
inline const gdcm::Tag kSopInstanceUid(0x0008, 0x0018);
inline const gdcm::Tag kAcquisitionTime(0x0008, 0x0032);
inline const gdcm::Tag kContentTime(0x0008, 0x0033);
inline const gdcm::Tag kModality(0x0008, 0x0060);
inline const gdcm::Tag kSeriesDescription(0x0008, 0x103e);
inline const gdcm::Tag kSliceThickness(0x0018, 0x0050);
inline const gdcm::Tag kSpacingBetweenSlices(0x0018, 0x0088);
inline const gdcm::Tag kGantryTilt(0x0018, 0x1120);
inline const gdcm::Tag kDiffusionBValue(0x0018, 0x9087);               // FD, s/mm^2
inline const gdcm::Tag kDiffusionGradientOrientation(0x0018, 0x9089);  // FD x3
inline const gdcm::Tag kSeriesUid(0x0020, 0x000e);
inline const gdcm::Tag kAcquisitionNumber(0x0020, 0x0012);
inline const gdcm::Tag kInstanceNumber(0x0020, 0x0013);
inline const gdcm::Tag kImagePosition(0x0020, 0x0032);
inline const gdcm::Tag kImageOrientation(0x0020, 0x0037);
inline const gdcm::Tag kTemporalPosition(0x0020, 0x0100);
inline const gdcm::Tag kNumberOfTemporalPositions(0x0020, 0x0105);
// Per frame of an enhanced multi-frame file (Frame Content Sequence (0020,9111)); palp keeps
// them as text like the other values (UL values as decimal numbers separated by '\').
inline const gdcm::Tag kFrameAcquisitionDateTime(0x0018, 0x9074);
inline const gdcm::Tag kTemporalPositionIndex(0x0020, 0x9128);
inline const gdcm::Tag kDimensionIndexValues(0x0020, 0x9157);
inline const gdcm::Tag kSamplesPerPixel(0x0028, 0x0002);
inline const gdcm::Tag kPhotometric(0x0028, 0x0004);
inline const gdcm::Tag kNumberOfFrames(0x0028, 0x0008);
inline const gdcm::Tag kRows(0x0028, 0x0010);
inline const gdcm::Tag kColumns(0x0028, 0x0011);
inline const gdcm::Tag kPixelSpacing(0x0028, 0x0030);
inline const gdcm::Tag kBitsAllocated(0x0028, 0x0100);
inline const gdcm::Tag kRescaleIntercept(0x0028, 0x1052);
inline const gdcm::Tag kRescaleSlope(0x0028, 0x1053);
inline const gdcm::Tag kPixelData(0x7fe0, 0x0010);

/// "UID (name)" for a transfer syntax UID: GDCM's name where GDCM knows the syntax, else the
/// name the DICOM standard gives newer syntaxes (HTJ2K, JPEG XL, video...), else "unknown
/// transfer syntax". Empty @p uid: "no transfer syntax".
std::string describeTransferSyntax(const std::string& uid);

/// Whether GDCM (as built here) knows the transfer syntax @p uid.
bool gdcmKnowsTransferSyntax(const std::string& uid);

/// @p s without leading and trailing blanks and NULs.
std::string trim(const std::string& s);

/// Parses a backslash-separated list of decimal numbers; nullopt when any is not a finite number.
std::optional<std::vector<double>> parseNumbers(const std::string& text);

/// One finite decimal number; nullopt otherwise.
std::optional<double> parseNumber(const std::string& text);

/// DICOM TM ("HHMMSS.FFFFFF", or the old "HH:MM:SS.frac") as seconds since midnight.
std::optional<double> parseTime(const std::string& text);

/// DICOM DT ("YYYYMMDDHHMMSS.FFFFFF", time optional, a "+HHMM" offset ignored) as seconds since
/// 1970-01-01; nullopt when it is not one.
std::optional<double> parseDateTime(const std::string& text);

/// What the header scan found in one file.
struct Header {
    std::filesystem::path path;
    std::map<gdcm::Tag, std::string> values;  // trimmed values of the scanned tags present
    /// 1-based frame of an enhanced multi-frame file this header describes (its values are the
    /// file's, overridden by the shared and the frame's functional groups); 0 for a whole file.
    int frame = 0;
    /// The scan's walk (walkFile) found the file's Pixel Data value (or all of its fragments)
    /// within the file, so checkComplete() need not parse the header again to measure it.
    bool pixelDataFits = false;

    /// The file, and the frame for a frame: "path (frame 7)", for messages.
    std::string label() const {
        return frame > 0 ? path.string() + " (frame " + std::to_string(frame) + ")" : path.string();
    }

    const std::string* get(const gdcm::Tag& t) const {
        const auto it = values.find(t);
        return it == values.end() || it->second.empty() ? nullptr : &it->second;
    }
    std::string text(const gdcm::Tag& t) const {
        const std::string* v = get(t);
        return v ? *v : std::string();
    }
    std::optional<double> number(const gdcm::Tag& t) const {
        const std::string* v = get(t);
        return v ? parseNumber(*v) : std::nullopt;
    }
    int integer(const gdcm::Tag& t, int fallback) const {
        const auto v = number(t);
        if (!v || *v < 0 || *v > 1e9) return fallback;
        return static_cast<int>(*v);
    }
    bool isImage() const { return integer(kRows, 0) > 0 && integer(kColumns, 0) > 0; }
};

/// Unit slice normal from a header's orientation, if it has a usable one.
std::optional<Eigen::Vector3d> normalOf(const Header& h);

/// Image Position (Patient) in mm, if present and well formed.
std::optional<Eigen::Vector3d> positionOf(const Header& h);

/// Parsed, checked geometry of one file (mm and unit cosines, as in DICOM).
struct FileGeometry {
    Eigen::Vector3d position;
    Eigen::Vector3d rowCosine, columnCosine;
    double rowSpacing = 0, columnSpacing = 0;  // PixelSpacing[0], PixelSpacing[1]
};

/// The checked geometry of @p h.
/// @throw FormatError naming the file when position, orientation or spacing is missing or bad.
FileGeometry geometryOf(const Header& h);

}  // namespace palp::volume::dicom
