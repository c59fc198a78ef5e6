// MetaImage reader (.mha with LOCAL data, .mhd with a separate data file): palp's own parser of
// the MetaIO text header; raw, zlib-compressed or ASCII data.
#include <Eigen/Core>
#include <array>
#include <cmath>
#include <limits>

#include "formats/formats.h"
#include "formats/header_parsers.h"
#include "formats/raw_data.h"
#include "formats/raw_slices.h"
#include "formats/reader_util.h"
#include "palp/base/error.h"
#include "palp/base/validate.h"
#include "time_point.h"

namespace palp::volume {

namespace fs = std::filesystem;
using detail::lower;
using detail::quoteFound;
using detail::trim;

namespace {

struct Entry {
    std::string key;    // lower case
    std::string value;  // trimmed
    int line = 0;
};

[[noreturn]] void fail(const std::string& name, const Entry& e, const std::string& expected) {
    throw FormatError(name + ": line " + std::to_string(e.line) + ": expected " + expected +
                      ", found " + quoteFound(e.value));
}

bool boolean(const std::string& name, const Entry& e, const char* key) {
    const std::string v = lower(e.value);
    if (v == "true" || v == "1" || v == "yes") return true;
    if (v == "false" || v == "0" || v == "no") return false;
    fail(name, e, std::string("'") + key + "' True or False");
}

std::vector<double> numbers(const std::string& name, const Entry& e, const char* key,
                            std::size_t n) {
    const auto w = detail::words(e.value);
    std::vector<double> out;
    for (const auto& tok : w) {
        const auto v = detail::toDouble(tok);
        if (!v || !std::isfinite(*v)) break;
        out.push_back(*v);
    }
    if (out.size() != n || w.size() != n) {
        fail(name, e, std::string("'") + key + "' with " + std::to_string(n) + " finite numbers");
    }
    return out;
}

}  // namespace

MetaImageHeader parseMetaImageHeader(std::string_view text, const std::string& name) {
    MetaImageHeader h;
    std::size_t pos = 0;
    int lineNo = 0;
    std::vector<Entry> entries;
    bool sawDataFile = false;
    while (pos < text.size()) {
        const std::size_t e = text.find('\n', pos);
        const std::size_t end = e == std::string_view::npos ? text.size() : e;
        std::string_view line = text.substr(pos, end - pos);
        pos = e == std::string_view::npos ? text.size() : e + 1;
        ++lineNo;
        if (!line.empty() && line.back() == '\r') line.remove_suffix(1);
        if (trim(line).empty()) continue;
        const std::size_t eq = line.find('=');
        if (eq == std::string_view::npos) {
            throw FormatError(name + ": line " + std::to_string(lineNo) +
                              ": expected 'Key = Value', found " + quoteFound(line));
        }
        Entry entry{lower(trim(line.substr(0, eq))), std::string(trim(line.substr(eq + 1))),
                    lineNo};
        if (entry.key.empty()) {
            throw FormatError(name + ": line " + std::to_string(lineNo) +
                              ": expected 'Key = Value', found " + quoteFound(line));
        }
        const bool isDataFile = entry.key == "elementdatafile";
        entries.push_back(std::move(entry));
        if (isDataFile) {
            sawDataFile = true;
            break;
        }
    }
    if (!sawDataFile) {
        throw FormatError(
            name + ": expected an 'ElementDataFile' line ending the MetaImage header, found " +
            (lineNo == 0 ? std::string("an empty header")
                         : "none in " + std::to_string(lineNo) + " lines"));
    }
    h.headerBytes = pos;

    auto find = [&](const char* key) -> const Entry* {
        const Entry* found = nullptr;
        for (const Entry& en : entries) {
            if (en.key == key) found = &en;  // the last one wins, as in MetaIO
        }
        return found;
    };
    auto require = [&](const char* key, const char* display) -> const Entry& {
        const Entry* en = find(key);
        if (!en)
            throw FormatError(name + ": expected a '" + std::string(display) +
                              "' line in the MetaImage header, found none");
        return *en;
    };

    if (const Entry* en = find("objecttype")) {
        if (lower(en->value) != "image") fail(name, *en, "'ObjectType' Image");
    }
    const Entry& eDims = require("ndims", "NDims");
    const auto nd = detail::toInt(eDims.value);
    if (!nd || *nd < 1 || *nd > kMaxAxes) fail(name, eDims, "'NDims' with an integer in [1, 16]");
    h.nDims = static_cast<int>(*nd);
    const auto n = static_cast<std::size_t>(h.nDims);

    const Entry& eSize = require("dimsize", "DimSize");
    for (const auto& tok : detail::words(eSize.value)) {
        const auto v = detail::toInt(tok);
        if (!v || *v <= 0)
            fail(name, eSize, "'DimSize' with " + std::to_string(n) + " positive integers");
        h.dimSize.push_back(*v);
    }
    if (h.dimSize.size() != n)
        fail(name, eSize, "'DimSize' with " + std::to_string(n) + " positive integers");

    h.elementSpacing.assign(n, 1.0);
    if (const Entry* en = find("elementspacing")) {
        h.elementSpacing = numbers(name, *en, "ElementSpacing", n);
    } else if (const Entry* es = find("elementsize")) {
        h.elementSpacing = numbers(name, *es, "ElementSize", n);
    }
    h.offset.assign(n, 0.0);
    for (const char* key : {"position", "origin", "offset"}) {
        if (const Entry* en = find(key)) h.offset = numbers(name, *en, "Offset", n);
    }
    h.transformMatrix.assign(n * n, 0.0);
    for (std::size_t i = 0; i < n; ++i) h.transformMatrix[i * n + i] = 1.0;
    for (const char* key : {"orientation", "rotation", "transformmatrix"}) {
        if (const Entry* en = find(key))
            h.transformMatrix = numbers(name, *en, "TransformMatrix", n * n);
    }
    if (const Entry* en = find("anatomicalorientation")) h.anatomicalOrientation = en->value;

    const Entry& eType = require("elementtype", "ElementType");
    {
        static const std::pair<const char*, ElementType> kTypes[] = {
            {"MET_CHAR", ElementType::Int8},       {"MET_UCHAR", ElementType::UInt8},
            {"MET_SHORT", ElementType::Int16},     {"MET_USHORT", ElementType::UInt16},
            {"MET_INT", ElementType::Int32},       {"MET_UINT", ElementType::UInt32},
            {"MET_LONG", ElementType::Int32},      {"MET_ULONG", ElementType::UInt32},
            {"MET_LONG_LONG", ElementType::Int64}, {"MET_ULONG_LONG", ElementType::UInt64},
            {"MET_FLOAT", ElementType::Float32},   {"MET_DOUBLE", ElementType::Float64},
        };
        bool ok = false;
        for (const auto& [k, t] : kTypes) {
            if (eType.value == k) {
                h.type = t;
                ok = true;
            }
        }
        if (!ok)
            fail(name, eType,
                 "'ElementType' MET_CHAR, MET_UCHAR, MET_SHORT, MET_USHORT, MET_INT, MET_UINT, "
                 "MET_LONG, MET_ULONG, MET_LONG_LONG, MET_ULONG_LONG, MET_FLOAT or MET_DOUBLE");
        h.typeGiven = true;
    }
    for (const char* key : {"binarydatabyteordermsb", "elementbyteordermsb"}) {
        if (const Entry* en = find(key))
            h.byteOrder =
                boolean(name, *en, "ElementByteOrderMSB") ? ByteOrder::Big : ByteOrder::Little;
    }
    if (const Entry* en = find("binarydata")) h.binaryData = boolean(name, *en, "BinaryData");
    if (const Entry* en = find("compresseddata"))
        h.compressed = boolean(name, *en, "CompressedData");
    if (const Entry* en = find("compresseddatasize")) {
        const auto v = detail::toInt(en->value);
        if (!v || *v <= 0) fail(name, *en, "'CompressedDataSize' with a positive integer");
        h.compressedDataSize = static_cast<std::uint64_t>(*v);
    }
    if (const Entry* en = find("elementnumberofchannels")) {
        const auto v = detail::toInt(en->value);
        if (!v || *v < 1 || *v > 1024)
            fail(name, *en, "'ElementNumberOfChannels' with an integer in [1, 1024]");
        h.channels = static_cast<int>(*v);
    }
    if (const Entry* en = find("headersize")) {
        const auto v = detail::toInt(en->value);
        if (!v || *v < -1 || *v > std::numeric_limits<std::int64_t>::max() / 4) {
            fail(name, *en, "'HeaderSize' with -1 or a non-negative integer");
        }
        h.headerSize = *v;
    }
    const Entry& eFile = entries.back();
    if (eFile.value.empty()) fail(name, eFile, "'ElementDataFile' LOCAL or a file name");
    h.elementDataFile = eFile.value;
    return h;
}

namespace detail {

LazySliceStack openMetaImage(const fs::path& path, const ReadOptions& options) {
    const std::string name = path.string();
    const std::string prefix = detail::readHeaderPrefix(path);
    const MetaImageHeader h = parseMetaImageHeader(prefix, name);

    if (h.nDims != 3 && h.nDims != 4) {
        throw FormatError(name + ": expected NDims 3 or 4, found " + std::to_string(h.nDims));
    }
    if (h.channels != 1) {
        throw FormatError(name + ": expected ElementNumberOfChannels 1 (scalar voxels), found " +
                          std::to_string(h.channels));
    }
    const std::uint64_t esize = elementSize(h.type);
    const std::uint64_t total = checkedDataBytes(h.dimSize, esize, options.maxSourceBytes, name);
    const auto n = static_cast<std::size_t>(h.nDims);
    for (std::size_t a = 0; a < 3; ++a) {
        if (h.dimSize[a] > std::numeric_limits<std::int32_t>::max()) {
            throw ValueError(name +
                             ": expected at most 2147483647 samples per spatial axis, found " +
                             std::to_string(h.dimSize[a]));
        }
    }
    const std::int64_t volumeCount = h.nDims == 4 ? h.dimSize[3] : 1;
    const int t = detail::chooseTimePoint(volumeCount, options, name);

    // Direction cosines: entries [a*n .. a*n+2] are the direction of axis a (ITK's layout).
    Eigen::Matrix3d axes;
    Eigen::Vector3d origin;
    for (std::size_t a = 0; a < 3; ++a) {
        for (std::size_t r = 0; r < 3; ++r) {
            axes(static_cast<Eigen::Index>(r), static_cast<Eigen::Index>(a)) =
                h.transformMatrix[a * n + r] * h.elementSpacing[a] * 1e-3;
        }
        origin[static_cast<Eigen::Index>(a)] = h.offset[a] * 1e-3;
    }
    // A spacing or direction the header gives is used or refused, never replaced.
    for (std::size_t a = 0; a < 3; ++a) {
        if (!std::isfinite(h.elementSpacing[a]) || h.elementSpacing[a] == 0) {
            throw FormatError(name + ": ElementSpacing (axis " + std::to_string(a) +
                              "): expected a finite non-zero spacing, found " +
                              formatValue(h.elementSpacing[a]));
        }
        const Eigen::Vector3d direction(h.transformMatrix[a * n], h.transformMatrix[a * n + 1],
                                        h.transformMatrix[a * n + 2]);
        if (!direction.allFinite() || direction.norm() == 0) {
            throw FormatError(name + ": TransformMatrix (axis " + std::to_string(a) +
                              "): expected a finite non-zero direction, found (" +
                              formatValue(direction.x()) + " " + formatValue(direction.y()) + " " +
                              formatValue(direction.z()) + ")");
        }
    }
    detail::checkAffine(name, "ElementSpacing", "TransformMatrix", "Offset", axes, origin);

    const std::uint64_t volumeBytes = total / static_cast<std::uint64_t>(volumeCount);
    const std::uint64_t volumeStart = t > 0 ? static_cast<std::uint64_t>(t) * volumeBytes : 0;

    fs::path dataPath = path;
    std::uint64_t offset = 0;
    const std::string fileWord = lower(h.elementDataFile);
    if (fileWord == "local") {
        offset = h.headerBytes;
    } else {
        if (fileWord.rfind("list", 0) == 0) {
            throw FormatError(
                name +
                ": expected 'ElementDataFile' LOCAL or a single file name, found LIST "
                "(palp does not read multi-file MetaImages)");
        }
        if (h.elementDataFile.find('%') != std::string::npos &&
            detail::words(h.elementDataFile).size() > 1) {
            throw FormatError(name +
                              ": expected 'ElementDataFile' LOCAL or a single file name, found the "
                              "printf-style multi-file form " +
                              quoteFound(h.elementDataFile));
        }
        const fs::path df(h.elementDataFile);
        dataPath = df.is_absolute() ? df : path.parent_path() / df;
    }

    const std::array<std::int64_t, 3> dims{h.dimSize[0], h.dimSize[1], h.dimSize[2]};
    LazySliceStack lazy;
    if (!h.binaryData) {
        std::vector<float> all = readAsciiValues(
            dataPath, offset + static_cast<std::uint64_t>(std::max<std::int64_t>(h.headerSize, 0)),
            total / esize);
        const auto first = static_cast<std::ptrdiff_t>(volumeStart / esize);
        std::vector<float> values(
            all.begin() + first,
            all.begin() + first + static_cast<std::ptrdiff_t>(volumeBytes / esize));
        all = {};
        lazy.stack = stackFromAffine(values, dims, axes, origin, name);
    } else {
        RawVolume raw;
        raw.file = dataPath;
        raw.item = name;
        raw.type = h.type;
        raw.order = h.byteOrder;
        raw.dims = dims;
        if (h.compressed) {
            if (h.headerSize == -1) {
                throw FormatError(name +
                                  ": expected 'HeaderSize' >= 0 with compressed data, found -1");
            }
            raw.compressed = true;
            raw.offset = offset + static_cast<std::uint64_t>(h.headerSize);
            raw.compressedLimit =
                h.compressedDataSize.value_or(std::numeric_limits<std::uint64_t>::max());
            raw.streamBytes = total;
            raw.volumeAt = volumeStart;
        } else {
            if (h.headerSize == -1) {
                const std::uint64_t fsz = fileSize(dataPath);
                if (fsz < offset + total) {
                    throw FormatError(
                        dataPath.string() + ": expected " + std::to_string(total) +
                        " bytes of voxel data at the end of the file (HeaderSize -1), found " +
                        std::to_string(fsz > offset ? fsz - offset : 0));
                }
                offset = fsz - total;
            } else {
                offset += static_cast<std::uint64_t>(h.headerSize);
            }
            // The whole data block must be there, though only the chosen volume is read.
            requireDataAfterHeader(dataPath, offset, total);
            raw.offset = offset + volumeStart;
        }
        lazy = openRawVolume(raw, axes, origin);
    }
    SliceStack& stack = lazy.stack;
    stack.info.sourceFormat = "MetaImage";
    stack.info.sourceDescription = path.filename().string();
    stack.info.timePoint = t;
    stack.info.timePointCount =
        static_cast<int>(std::min<std::int64_t>(volumeCount, std::numeric_limits<int>::max()));
    return lazy;
}

}  // namespace detail

SliceStack readMetaImage(const fs::path& path, const ReadOptions& options) {
    return detail::decodeAll(detail::openMetaImage(path, options));
}

}  // namespace palp::volume
