// NRRD reader: the header (nrrd_header.cpp), then raw/gzip/ascii data, attached or detached.
#include <Eigen/Core>
#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <span>

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

namespace {

/// Throws FormatError(`<what>: expected <expected>, found <found>`).
[[noreturn]] void throwFormat(const std::string& what, std::string_view expected,
                              const std::string& found) {
    throw FormatError(what + ": expected " + std::string(expected) + ", found " + found);
}

bool nonSpatialKind(const std::string& kind) {
    return !(kind.empty() || kind == "domain" || kind == "space" || kind == "???" ||
             kind == "none");
}

/// Which axes of a NRRD are spatial, and the one non-spatial axis with more than one sample
/// (the time points), if any.
struct AxisRoles {
    std::vector<int> spatial;
    int volumeAxis = -1;
    std::int64_t volumeCount = 1;
};

AxisRoles axisRoles(const NrrdHeader& h, const std::string& name) {
    const int n = h.dimension;
    AxisRoles roles;
    std::vector<int>& spatial = roles.spatial;
    int& volumeAxis = roles.volumeAxis;
    std::int64_t& volumeCount = roles.volumeCount;
    // Which axes are spatial.
    if (!h.spaceDirections.empty()) {
        for (int a = 0; a < n; ++a) {
            if (h.spaceDirections[static_cast<std::size_t>(a)]) spatial.push_back(a);
        }
    } else if (n == 3) {
        spatial = {0, 1, 2};
    } else if (!h.kinds.empty()) {
        for (int a = 0; a < n; ++a) {
            if (!nonSpatialKind(h.kinds[static_cast<std::size_t>(a)])) spatial.push_back(a);
        }
    } else if (n == 4) {
        spatial = {0, 1, 2};
    }
    if (spatial.size() != 3) {
        throw FormatError(name + ": expected 3 spatial axes (space directions or kinds), found " +
                          std::to_string(spatial.size()) + " of " + std::to_string(n) + " axes");
    }
    for (int a = 0; a < n; ++a) {
        if (std::find(spatial.begin(), spatial.end(), a) != spatial.end()) continue;
        const std::int64_t s = h.sizes[static_cast<std::size_t>(a)];
        if (s > 1) {
            if (volumeAxis >= 0) {
                throw FormatError(
                    name +
                    ": expected at most one non-spatial axis with more than one sample, "
                    "found axes " +
                    std::to_string(volumeAxis) + " and " + std::to_string(a));
            }
            volumeAxis = a;
            volumeCount = s;
        }
    }
    return roles;
}

/// The index-to-world affine of the spatial axes, in LPS metres.
/// @throw FormatError naming @p name when it is not finite.
void nrrdGeometry(const NrrdHeader& h, const std::vector<int>& spatial, const std::string& name,
                  Eigen::Matrix3d& axes, Eigen::Vector3d& origin) {
    // Geometry: index-to-world in LPS metres.
    axes = Eigen::Matrix3d::Zero();
    origin = Eigen::Vector3d::Zero();
    const double unit = h.spaceUnitsToMetres;
    if (!h.spaceDirections.empty()) {
        for (int c = 0; c < 3; ++c) {
            const Eigen::Vector3d& d =
                *h.spaceDirections[static_cast<std::size_t>(spatial[static_cast<std::size_t>(c)])];
            axes.col(c) = d.cwiseProduct(h.toLps) * unit;
        }
        if (h.spaceOrigin) origin = h.spaceOrigin->cwiseProduct(h.toLps) * unit;
    } else {
        for (int c = 0; c < 3; ++c) {
            const auto a = static_cast<std::size_t>(spatial[static_cast<std::size_t>(c)]);
            const bool cell = a < h.centerings.size() && h.centerings[a] == "cell";
            const auto samples = static_cast<double>(h.sizes[a]);
            // A spacing the file gives is used or refused, never replaced; 1 (mm) only when
            // the file says nothing about this axis's sample spacing.
            double step = 1.0;
            const std::string axis = " (axis " + std::to_string(a) + ")";
            if (h.spacingsGiven) {
                step = h.spacings[a];
                if (!std::isfinite(step) || step == 0) {
                    throwFormat(name + ": spacings" + axis,
                                "a finite non-zero spacing on a spatial axis", formatValue(step));
                }
            } else if (h.axisRangeGiven && std::isfinite(h.axisMins[a]) &&
                       std::isfinite(h.axisMaxs[a])) {
                const double intervals = cell ? samples : samples - 1;
                if (intervals > 0) {
                    step = (h.axisMaxs[a] - h.axisMins[a]) / intervals;
                    if (!std::isfinite(step) || step == 0) {
                        throwFormat(
                            name + ": axis mins, axis maxs" + axis,
                            "a finite non-empty range on a spatial axis",
                            formatValue(h.axisMins[a]) + " to " + formatValue(h.axisMaxs[a]));
                    }
                }
            }
            double start = 0;
            if (std::isfinite(h.axisMins[a])) start = h.axisMins[a] + (cell ? 0.5 * step : 0.0);
            axes(c, c) = step * h.toLps[c] * unit;
            origin[c] = start * h.toLps[c] * unit;
        }
    }
    if (!axes.allFinite() || !origin.allFinite()) {
        throw FormatError(name +
                          ": expected finite space directions and origin, found non-finite values");
    }
    if (h.spaceDirections.empty()) {
        detail::checkAffine(name, "spacings", "spacings", "axis mins", axes, origin);
    } else {
        detail::checkAffine(name, "space directions", "space directions", "space origin", axes,
                            origin);
    }
}

/// The voxel data of a NRRD as read: raw or inflated bytes (the first element at dataStart),
/// or the values of an ASCII file.
struct NrrdData {
    std::vector<std::byte> bytes;
    std::vector<float> asciiValues;
    std::uint64_t dataStart = 0;
};

/// The file holding the data @p h describes and where in it the data start: after the line skip
/// and, for raw data, the byte skip (-1: the last @p total bytes of the file); for gzip and ASCII
/// data the byte skip applies to what follows.
struct NrrdDataPlace {
    fs::path file;
    std::uint64_t offset = 0;
};

NrrdDataPlace placeNrrdData(const fs::path& path, const std::string& prefix, const NrrdHeader& h,
                            std::uint64_t total) {
    const std::string name = path.string();
    fs::path dataPath = path;
    std::uint64_t offset = 0;
    if (h.dataFile.empty()) {
        if (!h.blankLineEnd) {
            throw FormatError(
                name +
                ": expected an empty line ending the header before the attached data, found " +
                (prefix.size() >= kMaxHeaderBytes ? "none in the first 1 MiB"
                                                  : "the end of the file"));
        }
        offset = h.headerBytes;
    } else {
        const fs::path df(h.dataFile);
        dataPath = df.is_absolute() ? df : path.parent_path() / df;
    }
    offset = skipLines(dataPath, offset, h.lineSkip);
    if (h.encoding == NrrdEncoding::Raw) {
        if (h.byteSkip == -1) {
            const std::uint64_t fsz = fileSize(dataPath);
            if (fsz < offset + total) {
                throw FormatError(
                    dataPath.string() + ": expected " + std::to_string(total) +
                    " bytes of voxel data at the end of the file (byte skip -1), found " +
                    std::to_string(fsz > offset ? fsz - offset : 0));
            }
            offset = fsz - total;
        } else {
            offset += static_cast<std::uint64_t>(h.byteSkip);
        }
    }
    return {dataPath, offset};
}

/// Reads the @p total bytes (@p count elements) of voxel data that @p h describes; @p prefix is
/// what was read of the header file.
NrrdData readNrrdData(const fs::path& path, const std::string& prefix, const NrrdHeader& h,
                      std::uint64_t total, std::uint64_t count, const ReadOptions& options) {
    const std::string name = path.string();
    NrrdData d;
    std::vector<std::byte>& bytes = d.bytes;
    std::vector<float>& asciiValues = d.asciiValues;
    std::uint64_t& dataStart = d.dataStart;  // offset of the first element inside `bytes`
    const auto [dataPath, offset] = placeNrrdData(path, prefix, h, total);
    switch (h.encoding) {
        case NrrdEncoding::Raw: {
            bytes = readFileRange(dataPath, offset, total);
            break;
        }
        case NrrdEncoding::Gzip: {
            const auto skip = static_cast<std::uint64_t>(h.byteSkip);
            if (skip > options.maxSourceBytes - total) {
                throw ValueError(name + ": expected a byte skip of at most " +
                                 std::to_string(options.maxSourceBytes - total) + ", found " +
                                 std::to_string(skip));
            }
            bytes = inflateFileRange(dataPath, offset, std::numeric_limits<std::uint64_t>::max(),
                                     total + skip);
            dataStart = skip;
            break;
        }
        case NrrdEncoding::Ascii:
            asciiValues = readAsciiValues(
                dataPath,
                offset + static_cast<std::uint64_t>(std::max<std::int64_t>(h.byteSkip, 0)), count);
            break;
    }

    return d;
}

/// The stack's source fields for an NRRD.
void describeNrrd(SliceStack& stack, const NrrdHeader& h, const fs::path& path, int t,
                  std::int64_t volumeCount) {
    stack.info.sourceFormat = "NRRD";
    stack.info.sourceDescription = h.content.empty() ? path.filename().string() : h.content;
    stack.info.timePoint = t;
    stack.info.timePointCount =
        static_cast<int>(std::min<std::int64_t>(volumeCount, std::numeric_limits<int>::max()));
}

}  // namespace

namespace detail {

LazySliceStack openNrrd(const fs::path& path, const ReadOptions& options) {
    const std::string name = path.string();
    const std::string prefix = detail::readHeaderPrefix(path);
    const NrrdHeader h = parseNrrdHeader(prefix, name);
    const int n = h.dimension;
    const auto un = static_cast<std::size_t>(n);
    // Refuse impossible sizes before anything else is looked at or allocated.
    const std::uint64_t esize = elementSize(h.type);
    const std::uint64_t total = checkedDataBytes(h.sizes, esize, options.maxSourceBytes, name);
    const std::uint64_t count = total / esize;

    const AxisRoles roles = axisRoles(h, name);
    const std::vector<int>& spatial = roles.spatial;
    const int volumeAxis = roles.volumeAxis;
    const std::int64_t volumeCount = roles.volumeCount;
    const int t = detail::chooseTimePoint(volumeCount, options, name);
    for (const int a : spatial) {
        if (h.sizes[static_cast<std::size_t>(a)] > std::numeric_limits<std::int32_t>::max()) {
            throw ValueError(name +
                             ": expected at most 2147483647 samples per spatial axis, found " +
                             std::to_string(h.sizes[static_cast<std::size_t>(a)]));
        }
    }

    Eigen::Matrix3d axes;
    Eigen::Vector3d origin;
    nrrdGeometry(h, spatial, name, axes, origin);

    // The chosen volume stored contiguously (the spatial axes first and in order, a time axis,
    // if any, last) and as bytes: decoded a slice at a time.
    const bool inOrder = spatial.size() == 3 && spatial[0] == 0 && spatial[1] == 1 &&
                         spatial[2] == 2 && (volumeAxis < 0 || volumeAxis == 3);
    if (inOrder && h.encoding != NrrdEncoding::Ascii) {
        const std::uint64_t volumeBytes = total / static_cast<std::uint64_t>(volumeCount);
        const std::uint64_t volumeAt = t > 0 ? static_cast<std::uint64_t>(t) * volumeBytes : 0;
        const NrrdDataPlace place = placeNrrdData(path, prefix, h, total);
        RawVolume raw;
        raw.file = place.file;
        raw.item = name;
        raw.type = h.type;
        raw.order = h.endianGiven ? h.endian : nativeByteOrder();
        raw.dims = {h.sizes[0], h.sizes[1], h.sizes[2]};
        if (h.encoding == NrrdEncoding::Gzip) {
            const auto skip = static_cast<std::uint64_t>(h.byteSkip);
            if (skip > options.maxSourceBytes - total) {
                throw ValueError(name + ": expected a byte skip of at most " +
                                 std::to_string(options.maxSourceBytes - total) + ", found " +
                                 std::to_string(skip));
            }
            raw.compressed = true;
            raw.offset = place.offset;
            raw.streamBytes = total + skip;
            raw.volumeAt = skip + volumeAt;
        } else {
            // The whole data block must be there, though only the chosen volume is read.
            requireDataAfterHeader(place.file, place.offset, total);
            raw.offset = place.offset + volumeAt;
        }
        LazySliceStack lazy = openRawVolume(raw, axes, origin);
        describeNrrd(lazy.stack, h, path, t, volumeCount);
        return lazy;
    }

    NrrdData data = readNrrdData(path, prefix, h, total, count, options);
    std::vector<std::byte>& bytes = data.bytes;
    const std::vector<float>& asciiValues = data.asciiValues;
    const std::uint64_t dataStart = data.dataStart;

    // Gather the chosen volume with the spatial axes in file order (first spatial axis fastest).
    std::vector<std::uint64_t> stride(un, 1);
    for (std::size_t a = 1; a < un; ++a)
        stride[a] = stride[a - 1] * static_cast<std::uint64_t>(h.sizes[a - 1]);
    const std::uint64_t base = volumeAxis >= 0 ? static_cast<std::uint64_t>(t) *
                                                     stride[static_cast<std::size_t>(volumeAxis)]
                                               : 0;
    std::array<std::int64_t, 3> dims{};
    std::array<std::uint64_t, 3> st{};
    for (std::size_t c = 0; c < 3; ++c) {
        const auto a = static_cast<std::size_t>(spatial[c]);
        dims[c] = h.sizes[a];
        st[c] = stride[a];
    }
    const auto nx = static_cast<std::uint64_t>(dims[0]);
    const auto ny = static_cast<std::uint64_t>(dims[1]);
    const auto nz = static_cast<std::uint64_t>(dims[2]);
    std::vector<float> values(static_cast<std::size_t>(nx * ny * nz));
    const ByteOrder order = h.endianGiven ? h.endian : nativeByteOrder();
    const std::span<const std::byte> all(bytes);
    std::size_t out = 0;
    for (std::uint64_t k = 0; k < nz; ++k) {
        for (std::uint64_t j = 0; j < ny; ++j) {
            const std::uint64_t rowStart = base + j * st[1] + k * st[2];
            std::span<float> dst(values.data() + out, static_cast<std::size_t>(nx));
            if (h.encoding == NrrdEncoding::Ascii) {
                for (std::uint64_t i = 0; i < nx; ++i)
                    dst[i] = asciiValues[static_cast<std::size_t>(rowStart + i * st[0])];
            } else if (st[0] == 1) {
                decodeElements(all.subspan(static_cast<std::size_t>(dataStart + rowStart * esize),
                                           static_cast<std::size_t>(nx * esize)),
                               h.type, order, dst);
            } else {
                for (std::uint64_t i = 0; i < nx; ++i) {
                    decodeElements(all.subspan(static_cast<std::size_t>(
                                                   dataStart + (rowStart + i * st[0]) * esize),
                                               static_cast<std::size_t>(esize)),
                                   h.type, order, dst.subspan(static_cast<std::size_t>(i), 1));
                }
            }
            out += static_cast<std::size_t>(nx);
        }
    }
    bytes.clear();
    bytes.shrink_to_fit();

    LazySliceStack lazy;
    lazy.stack = stackFromAffine(values, dims, axes, origin, name);
    describeNrrd(lazy.stack, h, path, t, volumeCount);
    return lazy;
}

}  // namespace detail

SliceStack readNrrd(const fs::path& path, const ReadOptions& options) {
    return detail::decodeAll(detail::openNrrd(path, options));
}

}  // namespace palp::volume
