#pragma once
/// @file
/// Raw voxel data shared by the NIfTI, NRRD and MetaImage readers: element types, byte order,
/// decoding to float, bounded file reads, bounded zlib/gzip inflation and overflow-checked size
/// arithmetic. Every function that reads data checks the claimed size against what the file
/// holds, or grows its output incrementally, before allocating.

#include <cstddef>
#include <cstdint>
#include <filesystem>
#include <span>
#include <string>
#include <vector>

namespace palp::volume {

/// @p v as a float, with values beyond float's range as +-infinity (a plain cast of those is
/// undefined behaviour); NaN stays NaN. The load check (checkStackValues) then refuses them.
inline float saturatingFloat(double v) noexcept {
    constexpr double kMax = 3.4028234663852886e38;  // FLT_MAX
    if (v > kMax) return __builtin_huge_valf();
    if (v < -kMax) return -__builtin_huge_valf();
    return static_cast<float>(v);
}

/// Scalar element types of the supported formats.
enum class ElementType {
    Int8,
    UInt8,
    Int16,
    UInt16,
    Int32,
    UInt32,
    Int64,
    UInt64,
    Float32,
    Float64
};

/// Byte order of multi-byte elements in a file.
enum class ByteOrder { Little, Big };

/// Size of one element in bytes (1, 2, 4 or 8).
std::size_t elementSize(ElementType type);

/// Short name ("int16", "float32", ...) for messages.
const char* elementTypeName(ElementType type);

/// Byte order of this machine.
ByteOrder nativeByteOrder();

/// Converts @p out.size() elements of @p type stored in @p bytes with byte order @p order to
/// float. @p bytes must hold at least out.size() * elementSize(type) bytes.
/// @throw ValueError when @p bytes is too short (a programming error, never a file's fault).
void decodeElements(std::span<const std::byte> bytes, ElementType type, ByteOrder order,
                    std::span<float> out);

/// Multiplies @p dims and @p elementBytes with overflow checks. Returns the byte count.
/// @throw ValueError naming @p item when a dimension is not positive, the product overflows, or
///        it exceeds @p maxBytes (e.g. `scan.nrrd: expected at most 8589934592 bytes of voxel
///        data, found a header claiming 100000 x 100000 x 100000 x 2 bytes`).
std::uint64_t checkedDataBytes(std::span<const std::int64_t> dims, std::uint64_t elementBytes,
                               std::uint64_t maxBytes, const std::string& item);

/// Size of a regular file in bytes.
/// @throw IoError naming the file when it does not exist or is not readable.
std::uint64_t fileSize(const std::filesystem::path& path);

/// Checks that @p path holds @p count bytes from @p offset on, before anything is read.
/// @throw IoError when it cannot be read; FormatError naming it when it is shorter
///        (`<file>: expected 1234567 bytes of voxel data after the header, found 1000`).
void requireDataAfterHeader(const std::filesystem::path& path, std::uint64_t offset,
                            std::uint64_t count);

/// Reads @p count bytes at @p offset of @p path. The file size is checked before allocating.
/// @throw IoError when the file cannot be read, FormatError when it is too short
///        (`<file>: expected 1234567 bytes of voxel data after the header, found 1000`).
std::vector<std::byte> readFileRange(const std::filesystem::path& path, std::uint64_t offset,
                                     std::uint64_t count);

/// Inflates a zlib or gzip stream (auto-detected) starting at @p offset of @p path, reading at
/// most @p maxCompressedBytes compressed bytes (UINT64_MAX: to the end of the file). The output
/// grows incrementally and never beyond @p expectedBytes.
/// @throw IoError when unreadable; FormatError when the stream is corrupt, ends before
///        @p expectedBytes bytes or holds more than that.
std::vector<std::byte> inflateFileRange(const std::filesystem::path& path, std::uint64_t offset,
                                        std::uint64_t maxCompressedBytes,
                                        std::uint64_t expectedBytes);

/// inflateFileRange() keeping only the decompressed bytes [@p keepFrom, @p keepFrom +
/// @p keepCount) (one volume of a 4D file, the data after a NIfTI header), while checking the whole
/// stream. With @p allowTrailing the stream may hold more than @p expectedBytes (what follows is
/// not decompressed), as nifticlib reads a .nii.gz.
/// @throw ValueError when the window is not inside @p expectedBytes; as inflateFileRange().
std::vector<std::byte> inflateFileWindow(const std::filesystem::path& path, std::uint64_t offset,
                                         std::uint64_t maxCompressedBytes,
                                         std::uint64_t expectedBytes, std::uint64_t keepFrom,
                                         std::uint64_t keepCount, bool allowTrailing);

/// Access points into a zlib/gzip stream's deflate data, for decompressing any part of it
/// again without keeping its bytes (each point: where a deflate block starts, in and out, and the
/// 32 KiB of output before it that the block may refer to).
struct InflateIndex {
    struct Point {
        std::uint64_t out = 0;  ///< decompressed bytes before the point
        std::uint64_t in = 0;   ///< file offset of the first byte the point reads
        int bits = 0;           ///< unused high bits of the byte before @ref in that it reads
        std::vector<std::byte> window;
    };
    std::filesystem::path file;
    std::uint64_t end = 0;     ///< the file offset past the compressed data
    bool singleMember = true;  ///< points cover one gzip member; false: no random access
    std::vector<Point> points;
};

/// Checks the stream as inflateFileWindow() does (the same errors) while keeping none of its
/// bytes, and records points at deflate block boundaries at least @p spacing decompressed bytes
/// apart (~32 KiB each) for the bytes [@p keepFrom, @p keepFrom + @p keepCount): the last point
/// before the window and those inside it, so a 4D stream costs points for its chosen volume only.
/// A stream of several gzip members comes back with singleMember false.
InflateIndex indexFileStream(const std::filesystem::path& path, std::uint64_t offset,
                             std::uint64_t maxCompressedBytes, std::uint64_t expectedBytes,
                             std::uint64_t keepFrom, std::uint64_t keepCount, bool allowTrailing,
                             std::uint64_t spacing);

/// The decompressed bytes [@p from, @p from + out.size()) of @p index's stream, read by pread
/// from @p fd (the index's file, open; safe from several threads at once).
/// @throw FormatError when the file no longer holds them; Error for an unusable index.
void inflateAt(const InflateIndex& index, int fd, std::uint64_t from, std::span<std::byte> out);

/// In-memory variant of inflateFileRange; @p item names the source in messages.
std::vector<std::byte> inflateBytes(std::span<const std::byte> compressed,
                                    std::uint64_t expectedBytes, const std::string& item);

/// Parses @p count numbers (separated by white space or commas) from text at @p offset of
/// @p path. Refuses before allocating when the remaining file is too short to hold them.
/// @throw IoError, FormatError naming the file and the first bad token.
std::vector<float> readAsciiValues(const std::filesystem::path& path, std::uint64_t offset,
                                   std::uint64_t count);

/// Byte offset just after @p lines newline characters starting at @p offset of @p path.
/// @throw FormatError when the file ends first.
std::uint64_t skipLines(const std::filesystem::path& path, std::uint64_t offset,
                        std::int64_t lines);

}  // namespace palp::volume
