#include "dicom/dicom_walk.h"

#include <gdcmMediaStorage.h>

#include <algorithm>
#include <cstring>
#include <fstream>
#include <vector>

#include "dicom/dicom_header.h"
#include "palp/base/error.h"

namespace palp::volume::dicom {

namespace fs = std::filesystem;

namespace {

bool isLongVr(const char* vr) {
    static const char* const kLong[] = {"OB", "OD", "OF", "OL", "OV", "OW", "SQ",
                                        "SV", "UC", "UN", "UR", "UT", "UV"};
    for (const char* l : kLong) {
        if (vr[0] == l[0] && vr[1] == l[1]) return true;
    }
    return false;
}

}  // namespace

Walk walkFile(const fs::path& path) {
    Walk w;
    std::error_code ec;
    w.size = fs::file_size(path, ec);
    if (ec || w.size < 132) return w;
    std::ifstream in(path, std::ios::binary);
    char preamble[132];
    if (!in.read(preamble, 132) || std::memcmp(preamble + 128, "DICM", 4) != 0) return w;
    w.isPart10 = true;
    const std::uint64_t size = w.size;
    // The walk reads a few bytes per element: from a window of the file held here (a seekg per
    // element made the stream drop its buffer, so each element cost a seek and an 8 KB read:
    // ~150 system calls and ~1 MB copied per CT slice).
    constexpr std::uint64_t kWindow = 64 << 10;
    std::vector<unsigned char> window;
    std::uint64_t windowAt = 0;
    const auto readAt = [&](std::uint64_t at, unsigned char* buf, std::size_t n) {
        if (at + n > size) return false;
        if (at < windowAt || at + n > windowAt + window.size()) {
            windowAt = at;
            window.resize(
                static_cast<std::size_t>(std::min(size - at, std::max<std::uint64_t>(kWindow, n))));
            in.seekg(static_cast<std::streamoff>(at));
            if (!in.read(reinterpret_cast<char*>(window.data()),
                         static_cast<std::streamsize>(window.size()))) {
                window.clear();
                return false;
            }
        }
        std::memcpy(buf, window.data() + (at - windowAt), n);
        return true;
    };
    const auto fail = [&](const std::string& what, std::uint64_t at) {
        w.problem = what + " at byte " + std::to_string(at) + " of a " + std::to_string(size) +
                    "-byte file";
        return w;
    };
    bool metaDone = false, explicitVr = true, bigEndian = false, pixelData = false;
    std::string transferSyntax, mediaStorage;
    int depth = 0;  // open undefined-length sequences and items
    std::uint64_t pos = 132;
    while (pos < size) {
        unsigned char h[8];
        if (!readAt(pos, h, 4)) return fail("a truncated element header", pos);
        if (!metaDone && (h[0] | h[1] << 8) != 0x0002) {
            metaDone = true;
            if (transferSyntax == "1.2.840.10008.1.2") explicitVr = false;
            if (transferSyntax == "1.2.840.10008.1.2.2") bigEndian = true;
            if (transferSyntax == "1.2.840.10008.1.2.1.99") {  // deflated: GDCM inflates and checks
                w.complete = true;
                return w;
            }
        }
        const bool be = metaDone && bigEndian;
        const auto u16 = [&](const unsigned char* b) {
            return static_cast<std::uint32_t>(be ? (b[0] << 8 | b[1]) : (b[1] << 8 | b[0]));
        };
        const auto u32 = [&](const unsigned char* b) {
            return be ? (static_cast<std::uint32_t>(b[0]) << 24 |
                         static_cast<std::uint32_t>(b[1]) << 16 |
                         static_cast<std::uint32_t>(b[2]) << 8 | b[3])
                      : (static_cast<std::uint32_t>(b[3]) << 24 |
                         static_cast<std::uint32_t>(b[2]) << 16 |
                         static_cast<std::uint32_t>(b[1]) << 8 | b[0]);
        };
        const std::uint32_t group = u16(h), element = u16(h + 2);
        const std::uint64_t start = pos;
        if (pixelData && depth == 0 && group != 0xFFFE) {
            // Encapsulated pixel data holds only items and their delimiter: anything else is
            // damage to the pixel data, not to the header. A copy cut short and padded with
            // zeros (a failed transfer) leaves zeros to the end of the file.
            w.inPixelData = true;
            w.notAnItem = true;
            bool zeros = true;
            unsigned char chunk[4096];
            for (std::uint64_t at = pos; zeros && at < size; at += sizeof chunk) {
                const auto n =
                    static_cast<std::size_t>(std::min<std::uint64_t>(sizeof chunk, size - at));
                if (!readAt(at, chunk, n)) break;
                zeros = std::all_of(chunk, chunk + n, [](unsigned char c) { return c == 0; });
            }
            w.zeroedTail = zeros;
            return fail(zeros ? "zero bytes from here to the end of the file where pixel data "
                                "fragments were expected"
                              : "bytes that are no pixel data fragment item",
                        start);
        }
        std::uint32_t length = 0;
        char vr[2] = {0, 0};
        if (group == 0xFFFE) {  // item and delimiters: no VR
            if (!readAt(pos + 4, h, 4)) return fail("a truncated item header", start);
            length = u32(h);
            pos += 8;
        } else if (!metaDone || explicitVr) {
            if (!readAt(pos + 4, h, 4)) return fail("a truncated element header", start);
            vr[0] = static_cast<char>(h[0]);
            vr[1] = static_cast<char>(h[1]);
            if (vr[0] < 'A' || vr[0] > 'Z' || vr[1] < 'A' || vr[1] > 'Z')
                return fail("an invalid value representation", start);
            if (isLongVr(vr)) {
                if (!readAt(pos + 8, h, 4)) return fail("a truncated element header", start);
                length = u32(h);
                pos += 12;
            } else {
                length = u16(h + 2);
                pos += 8;
            }
        } else {
            if (!readAt(pos + 4, h, 4)) return fail("a truncated element header", start);
            length = u32(h);
            pos += 8;
        }
        const bool undefined = length == 0xFFFFFFFFu;
        if (group == 0xFFFE) {
            if (element == 0xE000 && !undefined) {
                if (pos + length > size) {
                    w.inPixelData = pixelData;
                    return fail(
                        pixelData ? "a truncated pixel data fragment" : "a truncated sequence item",
                        start);
                }
                pos += length;
            } else if (element == 0xE000) {
                ++depth;
            } else if (element == 0xE0DD && pixelData && depth == 0) {
                w.complete = true;
                w.pixelDataFits = true;
                return w;
            } else if (element == 0xE00D || element == 0xE0DD) {
                if (depth == 0) return fail("an unmatched delimiter", start);
                --depth;
            }
            continue;
        }
        if (undefined) {
            if (group == 0x7FE0 && element == 0x0010 && depth == 0) {
                pixelData = true;  // encapsulated fragments follow
            } else if (vr[0] == 'U' && vr[1] == 'N') {
                w.complete = true;  // implicit-VR content in an explicit file: leave it to GDCM
                return w;
            } else {
                ++depth;
            }
            continue;
        }
        if (depth == 0 && length <= 256 && pos + length <= size) {
            unsigned char v[256];
            if (readAt(pos, v, length)) {
                const std::string text = trim(std::string(reinterpret_cast<char*>(v), length));
                const std::uint32_t tag = group << 16 | element;
                if (tag == 0x00020010u) transferSyntax = w.transferSyntax = text;
                if (tag == 0x00020002u) mediaStorage = text;
                if (tag == 0x0020000Eu) w.seriesUid = text;
                if (length == 2 && tag == 0x00280010u) w.rows = static_cast<int>(u16(v));
                if (length == 2 && tag == 0x00280011u) w.cols = static_cast<int>(u16(v));
                if (length == 2 && tag == 0x00280100u) w.bitsAllocated = static_cast<int>(u16(v));
            }
        }
        if (pos + length > size) {
            w.inPixelData = group == 0x7FE0 && element == 0x0010;
            return fail(w.inPixelData
                            ? "a truncated pixel data value of " + std::to_string(length) + " bytes"
                            : "a truncated element value",
                        start);
        }
        pos += length;
        if (group == 0x7FE0 && element == 0x0010 && depth == 0) {
            w.complete = true;  // what follows Pixel Data (padding) does not matter
            w.pixelDataFits = true;
            return w;
        }
    }
    if (!metaDone) return fail("the end of the file within its file meta information", pos);
    // An image storage object that ends cleanly before any Pixel Data was cut short.
    if (!mediaStorage.empty() &&
        gdcm::MediaStorage::IsImage(gdcm::MediaStorage::GetMSType(mediaStorage.c_str()))) {
        w.noPixelData = true;
        return fail(
            "the end of an image file (SOP class " + mediaStorage + ") before any Pixel Data", pos);
    }
    if (depth != 0 || pixelData) return fail("an unterminated sequence", pos);
    w.complete = true;
    return w;
}

[[noreturn]] void throwDamaged(const fs::path& file, const Walk& w) {
    if (w.noPixelData) {
        throw FormatError(file.string() + ": expected Pixel Data (7fe0,0010) of " +
                          std::to_string(w.cols) + "x" + std::to_string(w.rows) + "x" +
                          std::to_string(w.bitsAllocated) + " bits, found none: " + w.problem +
                          " (the file is truncated or its pixel data was removed)");
    }
    if (w.inPixelData) {
        throw FormatError(file.string() + ": expected complete pixel data of " +
                          std::to_string(w.cols) + "x" + std::to_string(w.rows) + "x" +
                          std::to_string(w.bitsAllocated) + " bits, found " + w.problem +
                          (w.zeroedTail  ? " (the end of the file is zeroed: an incomplete copy)"
                           : w.notAnItem ? " (the pixel data is damaged)"
                                         : " (the file is truncated)"));
    }
    throw FormatError(file.string() + ": expected a complete DICOM header, found " + w.problem +
                      (w.seriesUid.empty()
                           ? std::string(" (its series cannot be told, so it is refused; remove it "
                                         "or list the other files explicitly)")
                           : std::string(" (series " + w.seriesUid + ")")));
}

}  // namespace palp::volume::dicom
