// NIfTI, NRRD and MetaImage volumes decoded a slice at a time.
#include "formats/raw_slices.h"

#include <fcntl.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>
#include <exception>
#include <limits>
#include <memory>
#include <span>
#include <vector>

#include "palp/base/bounds.h"
#include "palp/base/error.h"
#include "palp/base/parallel.h"

namespace palp::volume::detail {

namespace {

/// A file open for reading, closed with its last owner.
struct FileHandle {
    int fd = -1;
    ~FileHandle() {
        if (fd >= 0) ::close(fd);
    }
};

/// @p path opened for reading (pread from any thread), closed with the last decoder holding it.
std::shared_ptr<FileHandle> openHandle(const std::filesystem::path& path) {
    auto file = std::make_shared<FileHandle>();
    file->fd = ::open(path.c_str(), O_RDONLY | O_CLOEXEC);
    if (file->fd < 0) {
        throw IoError(path.string() + ": expected a readable file, found that open failed: " +
                      std::strerror(errno));
    }
    return file;
}

/// True when every value of @p raw, decoded and rescaled, is finite and within
/// bounds::kVolumeValue whatever the stored bits: integers up to 32 bits under a rescale that
/// maps their whole range inside the bounds (the slice check is then skipped, as for DICOM).
bool valuesBounded(const RawVolume& raw) {
    double lo = 0, hi = 0;
    switch (raw.type) {
        case ElementType::Int8:
            lo = -128, hi = 127;
            break;
        case ElementType::UInt8:
            hi = 255;
            break;
        case ElementType::Int16:
            lo = -32768, hi = 32767;
            break;
        case ElementType::UInt16:
            hi = 65535;
            break;
        case ElementType::Int32:
            lo = -2147483648.0, hi = 2147483647.0;
            break;
        case ElementType::UInt32:
            hi = 4294967295.0;
            break;
        default:
            return false;  // 64-bit integers and floats: checked value by value
    }
    const double a = raw.rescale ? raw.slope * lo + raw.intercept : lo;
    const double b = raw.rescale ? raw.slope * hi + raw.intercept : hi;
    // The float of a value within +-1e9 (less a margin for rounding) is within the bounds.
    constexpr double kSafe = 0.999 * 1e9;
    static_assert(bounds::kVolumeValue.min == -1e9 && bounds::kVolumeValue.max == 1e9);
    return std::abs(a) <= kSafe && std::abs(b) <= kSafe;
}

void toFloat(std::span<const std::byte> stored, const RawVolume& raw, std::vector<float>& values) {
    decodeElements(stored, raw.type, raw.order, values);
    if (raw.rescale) {
        for (float& v : values)
            v = saturatingFloat(raw.slope * static_cast<double>(v) + raw.intercept);
    }
}

}  // namespace

LazySliceStack openRawVolume(const RawVolume& raw, const Eigen::Matrix3d& axes,
                             const Eigen::Vector3d& origin) {
    const std::uint64_t esize = elementSize(raw.type);
    const auto nx = static_cast<std::uint64_t>(raw.dims[0]);
    const auto ny = static_cast<std::uint64_t>(raw.dims[1]);
    const auto nz = static_cast<std::uint64_t>(raw.dims[2]);
    const std::uint64_t sliceBytes = nx * ny * esize;  // the callers checked the product
    const std::uint64_t volumeBytes = sliceBytes * nz;

    LazySliceStack lazy;
    lazy.stack.slices.resize(static_cast<std::size_t>(nz));
    for (std::uint64_t k = 0; k < nz; ++k) {
        Slice& s = lazy.stack.slices[static_cast<std::size_t>(k)];
        s.position = origin + static_cast<double>(k) * axes.col(2);
        s.colStep = axes.col(0);
        s.rowStep = axes.col(1);
        s.cols = static_cast<std::int32_t>(nx);
        s.rows = static_cast<std::int32_t>(ny);
        s.source = raw.item;
    }
    lazy.stack.info.originalDims = raw.dims;
    lazy.stack.info.originalSpacing = {axes.col(0).norm(), axes.col(1).norm(), axes.col(2).norm()};
    const bool bounded = valuesBounded(raw);

    if (raw.compressed && volumeBytes >= raw.indexFromBytes) {
        // Access points about a slice apart: a slice decompresses at most ~two slices' bytes.
        auto index = std::make_shared<const InflateIndex>(indexFileStream(
            raw.file, raw.offset, raw.compressedLimit, raw.streamBytes, raw.volumeAt, volumeBytes,
            raw.trailingAllowed, std::max<std::uint64_t>(sliceBytes, std::uint64_t{1} << 18)));
        if (index->singleMember && !index->points.empty()) {
            auto file = openHandle(raw.file);
            lazy.decode = [file, index, raw, sliceBytes, bounded](std::size_t k, Slice& s) {
                thread_local std::vector<std::byte> stored;
                stored.resize(static_cast<std::size_t>(sliceBytes));
                inflateAt(*index, file->fd, raw.volumeAt + k * sliceBytes, stored);
                s.values.resize(static_cast<std::size_t>(sliceBytes / elementSize(raw.type)));
                toFloat(stored, raw, s.values);
                return bounded;
            };
            return lazy;
        }
        // Several gzip members: decompressed again below, the volume's bytes kept.
    }
    if (raw.compressed) {
        auto stored = std::make_shared<const std::vector<std::byte>>(
            inflateFileWindow(raw.file, raw.offset, raw.compressedLimit, raw.streamBytes,
                              raw.volumeAt, volumeBytes, raw.trailingAllowed));
        lazy.decode = [stored, raw, sliceBytes, bounded](std::size_t k, Slice& s) {
            s.values.resize(static_cast<std::size_t>(sliceBytes / elementSize(raw.type)));
            toFloat(
                std::span<const std::byte>(*stored).subspan(
                    static_cast<std::size_t>(k * sliceBytes), static_cast<std::size_t>(sliceBytes)),
                raw, s.values);
            return bounded;
        };
        return lazy;
    }

    const std::uint64_t size = fileSize(raw.file);
    if (size < raw.offset || size - raw.offset < volumeBytes) {
        throw FormatError(raw.file.string() + ": expected " + std::to_string(volumeBytes) +
                          " bytes of voxel data at byte " + std::to_string(raw.offset) +
                          ", found " + std::to_string(size > raw.offset ? size - raw.offset : 0));
    }
    auto file = openHandle(raw.file);
    lazy.decode = [file, raw, sliceBytes, bounded](std::size_t k, Slice& s) {
        // One slice's stored bytes, read into a buffer per thread and converted in place.
        thread_local std::vector<std::byte> stored;
        stored.resize(static_cast<std::size_t>(sliceBytes));
        std::uint64_t done = 0;
        const std::uint64_t at = raw.offset + k * sliceBytes;
        while (done < sliceBytes) {
            const ssize_t got =
                ::pread(file->fd, stored.data() + done, static_cast<std::size_t>(sliceBytes - done),
                        static_cast<off_t>(at + done));
            if (got < 0 && errno == EINTR) continue;
            if (got <= 0) {
                throw FormatError(raw.file.string() + ": expected " + std::to_string(sliceBytes) +
                                  " bytes of slice " + std::to_string(k) + " at byte " +
                                  std::to_string(at) + ", found " +
                                  (got < 0 ? std::string("a read error: ") + std::strerror(errno)
                                           : std::to_string(done) + " (the file shrank)"));
            }
            done += static_cast<std::uint64_t>(got);
        }
        s.values.resize(static_cast<std::size_t>(sliceBytes / elementSize(raw.type)));
        toFloat(stored, raw, s.values);
        return bounded;
    };
    return lazy;
}

SliceStack decodeAll(LazySliceStack&& lazy) {
    SliceStack stack = std::move(lazy.stack);
    if (!lazy.decode) return stack;
    std::vector<std::exception_ptr> errors(stack.slices.size());
    palp::parallelForEach(
        std::size_t{0}, stack.slices.size(),
        [&](std::size_t k) {
            try {
                (void)lazy.decode(k, stack.slices[k]);
            } catch (...) {
                errors[k] = std::current_exception();
            }
        },
        std::size_t{1});
    for (const std::exception_ptr& e : errors)
        if (e) std::rethrow_exception(e);
    return stack;
}

}  // namespace palp::volume::detail
