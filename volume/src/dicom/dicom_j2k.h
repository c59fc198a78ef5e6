#pragma once
// Damage in lossless JPEG 2000 pixel data (internal). GDCM decodes JPEG 2000 through OpenJPEG
// and reports only OpenJPEG's hard errors; a changed byte inside a code-block's arithmetic-coded
// data decodes "successfully" into wrong pixels (measured: 10,617 wrong voxels on one slice of
// the tilted CT). The check here decodes each codestream once more with OpenJPEG, asking for
// its predictable-termination check (see checkLosslessJpeg2000).
#include <cstddef>
#include <string>

namespace palp::volume::dicom {

/// Whether the transfer syntax @p uid is one whose codestreams checkLosslessJpeg2000 applies
/// to: JPEG 2000 Image Compression (Lossless Only), 1.2.840.10008.1.2.4.90.
bool isLosslessJpeg2000(const std::string& uid);

/// What is wrong with the JPEG 2000 codestream @p data (@p size bytes, from SOC to EOC); empty
/// when nothing is.
///
/// In a lossless codestream every coding pass of every code-block is present, so each
/// code-block's MQ (arithmetic) codeword segment is complete: decoding all of its passes uses
/// the segment's bytes and reads at most two bytes past its end (the bound OpenJPEG applies to
/// predictable termination, ISO 15444-1 D.4.2). A changed byte desynchronises the arithmetic
/// decoder, which then stops far from the end of the segment or runs past it. OpenJPEG
/// measures this only for code-blocks whose style declares predictable termination (PTERM), so
/// the check decodes a private copy of the codestream whose COD/COC markers declare it (the
/// flag changes no decoded value) and reports OpenJPEG's first warning or error. Measured on
/// a 512x512 CT slice encoded by `gdcmconv --j2k`: 298 of 303 single-byte changes spread over
/// the codestream were found, the intact stream passes.
/// Not applied to lossy streams, whose code-blocks may end mid-codeword by design.
std::string checkLosslessJpeg2000(const unsigned char* data, std::size_t size);

}  // namespace palp::volume::dicom
