#pragma once
// The structural walk of a DICOM file (internal): element headers read and values skipped, so
// that a damaged file is refused with a clear message before GDCM sees it.
#include <cstdint>
#include <filesystem>
#include <string>

namespace palp::volume::dicom {

/// What a structural walk of a file found. GDCM (as Debian builds it) aborts on an assertion
/// for some files that end inside an element header, so files are checked here, by reading
/// element headers and skipping values, before GDCM sees them.
struct Walk {
    bool isPart10 = false;       // "DICM" at byte 128
    bool complete = false;       // every header and value through the end of Pixel Data fits
    bool inPixelData = false;    // the damage lies in the Pixel Data value
    bool noPixelData = false;    // an image file that ends cleanly before Pixel Data
    bool pixelDataFits = false;  // the walk reached the end of the top-level Pixel Data value
    bool notAnItem = false;      // encapsulated pixel data holds something other than an item
    bool zeroedTail = false;     // ... which is zero bytes to the end of the file
    std::string problem;         // what is wrong, for messages
    std::string seriesUid;       // (0020,000e) when it was reached
    std::string transferSyntax;  // (0002,0010) as the file meta information gives it
    int rows = 0, cols = 0, bitsAllocated = 0;
    std::uint64_t size = 0;
};

/// Walks @p path's elements through the end of its Pixel Data.
Walk walkFile(const std::filesystem::path& path);

/// Refuses the damaged @p file, saying what @p w found.
/// @throw FormatError always.
[[noreturn]] void throwDamaged(const std::filesystem::path& file, const Walk& w);

}  // namespace palp::volume::dicom
