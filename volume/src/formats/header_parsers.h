#pragma once
/// @file
/// Pure text parsers for NRRD and MetaImage headers. They touch no file, allocate only in
/// proportion to the header text, and throw FormatError/ValueError naming @p name, the line and
/// what was expected. The readers (formats.h) and the fuzz targets call them.

#include <Eigen/Core>
#include <cstdint>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "formats/raw_data.h"

namespace palp::volume {

/// Largest header palp accepts (bytes); a file without a header end within this is refused.
inline constexpr std::size_t kMaxHeaderBytes = std::size_t{1} << 20;

/// Largest number of axes accepted in NRRD or MetaImage headers.
inline constexpr int kMaxAxes = 16;

/// Encodings of NRRD voxel data palp reads.
enum class NrrdEncoding { Raw, Gzip, Ascii };

/// A parsed NRRD header. Geometry is as written in the file (millimetres, in the file's space);
/// the reader converts to LPS metres.
struct NrrdHeader {
    int version = 0;  ///< N of NRRD000N
    ElementType type = ElementType::UInt8;
    int dimension = 0;                ///< number of axes
    std::vector<std::int64_t> sizes;  ///< samples per axis, axis 0 fastest
    /// Sign applied to world x, y, z to reach LPS: (-1, -1, 1) for RAS, (1, 1, 1) for LPS.
    Eigen::Vector3d toLps = Eigen::Vector3d::Ones();
    std::string space;       ///< canonical space name, "" when absent
    int spaceDimension = 0;  ///< 0 when no space or space dimension field
    /// Per axis: direction vector (first 3 components, mm) or nullopt for "none".
    std::vector<std::optional<Eigen::Vector3d>> spaceDirections;
    std::optional<Eigen::Vector3d> spaceOrigin;  ///< mm, first 3 components
    double spaceUnitsToMetres = 1e-3;            ///< from "space units" (mm by default)
    std::vector<double> spacings;                ///< per axis, NaN when absent
    bool spacingsGiven = false;                  ///< a "spacings" field was present
    bool axisRangeGiven = false;                 ///< both "axis mins" and "axis maxs" present
    std::vector<double> axisMins;                ///< per axis, NaN when absent
    std::vector<double> axisMaxs;                ///< per axis, NaN when absent
    std::vector<std::string> centerings;  ///< per axis ("cell", "node", "???"), empty when absent
    std::vector<std::string> kinds;       ///< per axis, empty when absent
    bool endianGiven = false;
    ByteOrder endian = ByteOrder::Little;
    NrrdEncoding encoding = NrrdEncoding::Raw;
    bool encodingGiven = false;
    std::string dataFile;  ///< detached data file name as written, "" when attached
    std::int64_t lineSkip = 0;
    std::int64_t byteSkip = 0;    ///< -1: data are the last bytes of the file (raw only)
    std::size_t headerBytes = 0;  ///< offset of attached data (after the blank line)
    bool blankLineEnd = false;    ///< the header ended with an empty line (not end of text)
    std::string content;          ///< "content" field, "" when absent
};

/// Parses the NRRD header at the start of @p text (the whole file or its first bytes). The header
/// ends at the first empty line or at the end of @p text. Checks required fields and the
/// consistency of per-axis fields with `dimension`.
/// @throw FormatError `<name>: line N: expected ..., found ...`.
NrrdHeader parseNrrdHeader(std::string_view text, const std::string& name);

/// A parsed MetaImage header (.mha or .mhd). Geometry in millimetres, world frame as written
/// (MetaImage/ITK world is LPS).
struct MetaImageHeader {
    int nDims = 0;
    std::vector<std::int64_t> dimSize;
    std::vector<double> elementSpacing;   ///< mm per axis (1 when absent)
    std::vector<double> offset;           ///< mm, nDims values (0 when absent)
    std::vector<double> transformMatrix;  ///< nDims*nDims, column-major direction cosines
    std::string anatomicalOrientation;    ///< e.g. "RAI", informational
    ElementType type = ElementType::UInt8;
    bool typeGiven = false;
    ByteOrder byteOrder = ByteOrder::Little;
    bool binaryData = true;
    bool compressed = false;
    std::optional<std::uint64_t> compressedDataSize;
    int channels = 1;
    std::int64_t headerSize = 0;  ///< bytes to skip in the data file, -1: tail
    std::string elementDataFile;  ///< "LOCAL" or a file name
    std::size_t headerBytes = 0;  ///< offset of LOCAL data (after ElementDataFile line)
};

/// Parses a MetaImage header from the start of @p text; it ends at the ElementDataFile line.
/// Unknown keys are ignored, as MetaIO does.
/// @throw FormatError `<name>: line N: expected ..., found ...`.
MetaImageHeader parseMetaImageHeader(std::string_view text, const std::string& name);

}  // namespace palp::volume
