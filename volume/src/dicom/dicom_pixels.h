#pragma once
// Decoding DICOM pixel data (internal): gdcm::ImageReader for every transfer syntax GDCM
// decodes, checks that the data is complete, and conversion of stored values to rescaled floats.
#include <gdcmImageReader.h>
#include <gdcmPixelFormat.h>

#include <cstddef>
#include <optional>
#include <string>
#include <vector>

#include "dicom/dicom_header.h"
#include "palp/volume/slice_stack.h"

namespace palp::volume::dicom {

/// Converts one frame of @p pf pixels at @p raw to rescaled floats (slope * stored + intercept).
/// Returns true when every value is known to lie within bounds::kVolumeValue from the pixel type
/// and the rescale alone (8 and 16-bit integers with a moderate rescale, as CT), so the caller
/// need not check each value; false when it must.
/// @throw FormatError for a pixel type other than 8, 16 or 32-bit integers or floats.
bool convertFrame(const std::string& file, const char* raw, const gdcm::PixelFormat& pf,
                  std::size_t count, double slope, double intercept, std::vector<float>& out);

/// Reads @p h with @p reader and decodes all of its @p frames frames into @p buffer, checking
/// the result against the header's Rows and Columns.
/// @throw FormatError naming the file when it is damaged, truncated or cannot be decoded.
void decodeFile(const Header& h, int frames, gdcm::ImageReader& reader, std::vector<char>& buffer);

/// @p slope, or 1 when absent.
/// @throw FormatError naming @p file for a zero slope (@p text is the value found).
double checkedSlope(const std::string& file, const std::optional<double>& slope,
                    const std::string& text);

/// Decodes one single-frame image into @p slice (values rescaled with the file's own slope and
/// intercept). Geometry is filled by the caller. Returns what convertFrame() returns.
bool decodeSlice(const Header& h, Slice& slice);

}  // namespace palp::volume::dicom
