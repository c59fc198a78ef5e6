#include "formats/raw_data.h"

#include <fcntl.h>
#include <unistd.h>
#include <zlib.h>

#include <algorithm>
#include <bit>
#include <cctype>
#include <cerrno>
#include <charconv>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <limits>
#include <string>
#include <type_traits>

#include "palp/base/error.h"

namespace palp::volume {

namespace fs = std::filesystem;

namespace {

template <typename T>
void decodeTyped(const std::byte* src, bool swap, std::span<float> out) {
    constexpr std::size_t kSize = sizeof(T);
    for (std::size_t i = 0; i < out.size(); ++i) {
        unsigned char buf[kSize];
        std::memcpy(buf, src + i * kSize, kSize);
        if (swap) std::reverse(buf, buf + kSize);
        T v;
        std::memcpy(&v, buf, kSize);
        if constexpr (std::is_same_v<T, double>) {
            out[i] = saturatingFloat(v);
        } else {
            out[i] = static_cast<float>(v);
        }
    }
}

std::ifstream openOrThrow(const fs::path& path) {
    std::ifstream in(path, std::ios::binary);
    if (!in)
        throw IoError(path.string() +
                      ": expected a readable file, found one that cannot be opened");
    return in;
}

}  // namespace

std::size_t elementSize(ElementType type) {
    switch (type) {
        case ElementType::Int8:
        case ElementType::UInt8:
            return 1;
        case ElementType::Int16:
        case ElementType::UInt16:
            return 2;
        case ElementType::Int32:
        case ElementType::UInt32:
        case ElementType::Float32:
            return 4;
        case ElementType::Int64:
        case ElementType::UInt64:
        case ElementType::Float64:
            return 8;
    }
    return 1;
}

const char* elementTypeName(ElementType type) {
    switch (type) {
        case ElementType::Int8:
            return "int8";
        case ElementType::UInt8:
            return "uint8";
        case ElementType::Int16:
            return "int16";
        case ElementType::UInt16:
            return "uint16";
        case ElementType::Int32:
            return "int32";
        case ElementType::UInt32:
            return "uint32";
        case ElementType::Int64:
            return "int64";
        case ElementType::UInt64:
            return "uint64";
        case ElementType::Float32:
            return "float32";
        case ElementType::Float64:
            return "float64";
    }
    return "unknown";
}

ByteOrder nativeByteOrder() {
    return std::endian::native == std::endian::big ? ByteOrder::Big : ByteOrder::Little;
}

void decodeElements(std::span<const std::byte> bytes, ElementType type, ByteOrder order,
                    std::span<float> out) {
    const std::size_t size = elementSize(type);
    if (bytes.size() / size < out.size()) {
        throw ValueError("decodeElements: expected " + std::to_string(out.size() * size) +
                         " bytes, found " + std::to_string(bytes.size()));
    }
    const bool swap = size > 1 && order != nativeByteOrder();
    const std::byte* src = bytes.data();
    switch (type) {
        case ElementType::Int8:
            decodeTyped<std::int8_t>(src, swap, out);
            break;
        case ElementType::UInt8:
            decodeTyped<std::uint8_t>(src, swap, out);
            break;
        case ElementType::Int16:
            decodeTyped<std::int16_t>(src, swap, out);
            break;
        case ElementType::UInt16:
            decodeTyped<std::uint16_t>(src, swap, out);
            break;
        case ElementType::Int32:
            decodeTyped<std::int32_t>(src, swap, out);
            break;
        case ElementType::UInt32:
            decodeTyped<std::uint32_t>(src, swap, out);
            break;
        case ElementType::Int64:
            decodeTyped<std::int64_t>(src, swap, out);
            break;
        case ElementType::UInt64:
            decodeTyped<std::uint64_t>(src, swap, out);
            break;
        case ElementType::Float32:
            decodeTyped<float>(src, swap, out);
            break;
        case ElementType::Float64:
            decodeTyped<double>(src, swap, out);
            break;
    }
}

std::uint64_t checkedDataBytes(std::span<const std::int64_t> dims, std::uint64_t elementBytes,
                               std::uint64_t maxBytes, const std::string& item) {
    std::string claim;
    for (const std::int64_t d : dims) claim += std::to_string(d) + " x ";
    claim += std::to_string(elementBytes) + " bytes";
    std::uint64_t total = elementBytes;
    bool overflow = false;
    for (const std::int64_t d : dims) {
        if (d <= 0) {
            throw ValueError(item + ": expected positive dimensions, found " + claim);
        }
        const auto ud = static_cast<std::uint64_t>(d);
        if (total > std::numeric_limits<std::uint64_t>::max() / ud) {
            overflow = true;
            break;
        }
        total *= ud;
    }
    if (overflow || total > maxBytes) {
        throw ValueError(item + ": expected at most " + std::to_string(maxBytes) +
                         " bytes of voxel data, found a header claiming " + claim +
                         (overflow ? " (more than 2^64)" : " = " + std::to_string(total)));
    }
    return total;
}

std::uint64_t fileSize(const fs::path& path) {
    std::error_code ec;
    if (!fs::is_regular_file(path, ec)) {
        throw IoError(path.string() + ": expected a regular file, found " +
                      (fs::exists(path, ec) ? "something else" : "nothing"));
    }
    const std::uintmax_t size = fs::file_size(path, ec);
    if (ec)
        throw IoError(path.string() +
                      ": expected a readable file, found an error: " + ec.message());
    return static_cast<std::uint64_t>(size);
}

void requireDataAfterHeader(const fs::path& path, std::uint64_t offset, std::uint64_t count) {
    const std::uint64_t size = fileSize(path);
    if (size < offset || size - offset < count) {
        throw FormatError(path.string() + ": expected " + std::to_string(count) +
                          " bytes of voxel data after the header, found " +
                          std::to_string(size > offset ? size - offset : 0));
    }
}

std::vector<std::byte> readFileRange(const fs::path& path, std::uint64_t offset,
                                     std::uint64_t count) {
    const std::uint64_t size = fileSize(path);
    const std::uint64_t available = size > offset ? size - offset : 0;
    if (available < count) {
        throw FormatError(path.string() + ": expected " + std::to_string(count) +
                          " bytes of voxel data after the header (at byte " +
                          std::to_string(offset) + "), found " + std::to_string(available));
    }
    std::ifstream in = openOrThrow(path);
    in.seekg(static_cast<std::streamoff>(offset));
    std::vector<std::byte> data(static_cast<std::size_t>(count));
    in.read(reinterpret_cast<char*>(data.data()), static_cast<std::streamsize>(count));
    if (static_cast<std::uint64_t>(in.gcount()) != count) {
        throw IoError(path.string() + ": expected " + std::to_string(count) +
                      " readable bytes, found " + std::to_string(in.gcount()));
    }
    return data;
}

namespace {

/// Streams compressed bytes from @p next (returns a chunk; empty at the end) and keeps the
/// decompressed bytes [keepFrom, keepFrom + keepCount) of the stream, in a buffer that grows as
/// they arrive (never beyond keepCount, so a header claiming a huge size allocates nothing a small
/// stream does not fill). The stream must hold exactly @p expectedBytes (or at least that many
/// with @p allowTrailing, whose extra bytes are then not decompressed).
/// Sees what inflateStream() decompresses, to index the stream (indexFileStream()).
struct InflateObserver {
    virtual ~InflateObserver() = default;
    /// Every decompressed byte, in order (the bytes of later gzip members too).
    virtual void output(std::span<const std::byte> bytes) = 0;
    /// At the start of the first member's data and at each of its deflate block boundaries:
    /// @p produced bytes out, @p consumed compressed bytes in, @p bits unused bits of the last.
    virtual void boundary(std::uint64_t produced, std::uint64_t consumed, int bits) = 0;
    /// A second gzip member starts.
    virtual void anotherMember() = 0;
};

template <typename NextChunk>
std::vector<std::byte> inflateStream(NextChunk&& next, std::uint64_t expectedBytes,
                                     const std::string& item, std::uint64_t keepFrom,
                                     std::uint64_t keepCount, bool allowTrailing,
                                     std::uint64_t compressedBytes,
                                     InflateObserver* observer = nullptr) {
    z_stream zs{};
    if (inflateInit2(&zs, 15 + 32) != Z_OK) {
        throw Error(item + ": expected zlib to initialise, found an error");
    }
    struct Guard {
        z_stream* s;
        ~Guard() { inflateEnd(s); }
    } guard{&zs};

    const std::uint64_t keepEnd = keepFrom + keepCount;  // <= expectedBytes (callers' check)
    std::vector<std::byte> out;
    // Room for what @p compressedBytes can decompress to at most (deflate expands no byte more
    // than 1032-fold), so the output grows in place: a buffer doubled and copied held 1.5x the
    // data at its last step. A header's size alone reserves nothing a small stream cannot fill.
    constexpr std::uint64_t kMaxRatio = 1032;
    out.reserve(static_cast<std::size_t>(std::min<std::uint64_t>(
        keepCount, compressedBytes > (std::numeric_limits<std::uint64_t>::max() >> 11)
                       ? keepCount
                       : compressedBytes * kMaxRatio + (std::uint64_t{1} << 16))));
    std::vector<std::byte> discard;  // bytes before or after the kept window
    std::uint64_t produced = 0;
    constexpr std::uint64_t kFirstChunk = std::uint64_t{1} << 20;
    bool ended = false;
    bool inputDone = false;
    std::byte overflowProbe[1];
    for (;;) {
        if (zs.avail_in == 0 && !inputDone) {
            std::span<const std::byte> chunk = next();
            if (chunk.empty()) {
                inputDone = true;
            } else {
                zs.next_in = reinterpret_cast<Bytef*>(const_cast<std::byte*>(chunk.data()));
                zs.avail_in = static_cast<uInt>(chunk.size());
            }
        }
        // Inside the window: straight into the output, grown geometrically; outside it: into a
        // scratch buffer; once the expected bytes are in, a one-byte probe detects a longer
        // stream without allocating.
        const bool probing = produced == expectedBytes;
        if (probing && allowTrailing) {
            ended = true;
            break;
        }
        if (probing) {
            zs.next_out = reinterpret_cast<Bytef*>(overflowProbe);
            zs.avail_out = 1;
        } else if (produced >= keepFrom && produced < keepEnd) {
            const std::uint64_t at = produced - keepFrom;
            if (at == out.size()) {
                const std::uint64_t grown = std::min<std::uint64_t>(
                    keepCount, std::max<std::uint64_t>(kFirstChunk, out.size() * 2));
                out.resize(static_cast<std::size_t>(grown));
            }
            const std::uint64_t room =
                std::min<std::uint64_t>(out.size() - at, std::uint64_t{1} << 30);
            zs.next_out = reinterpret_cast<Bytef*>(out.data() + at);
            zs.avail_out = static_cast<uInt>(room);
        } else {
            if (discard.empty()) discard.resize(std::size_t{1} << 18);
            const std::uint64_t limit = produced < keepFrom ? keepFrom : expectedBytes;
            zs.next_out = reinterpret_cast<Bytef*>(discard.data());
            zs.avail_out =
                static_cast<uInt>(std::min<std::uint64_t>(discard.size(), limit - produced));
        }
        const uInt availBefore = zs.avail_out;
        // An observer stops inflate at every block boundary (Z_BLOCK) to see it.
        const int rc = inflate(&zs, observer ? Z_BLOCK : Z_NO_FLUSH);
        const uInt written = availBefore - zs.avail_out;
        if (observer) {
            observer->output({reinterpret_cast<const std::byte*>(zs.next_out) - written, written});
            // Bit 7: at the end of a block or of the header; bit 6: the last block ended.
            if ((zs.data_type & 128) != 0 && (zs.data_type & 64) == 0 && rc == Z_OK)
                observer->boundary(produced + written, zs.total_in, zs.data_type & 7);
        }
        if (probing && written > 0) {
            throw FormatError(item + ": expected " + std::to_string(expectedBytes) +
                              " bytes of decompressed voxel data, found more");
        }
        produced += written;
        if (rc == Z_STREAM_END) {
            // Concatenated gzip members continue the data; anything else after the end is ignored.
            const bool moreInput = zs.avail_in > 0 || !inputDone;
            if (produced < expectedBytes && moreInput && zs.avail_in > 0) {
                inflateReset(&zs);
                if (observer) observer->anotherMember();
                continue;
            }
            ended = true;
            break;
        }
        if (rc == Z_BUF_ERROR || rc == Z_OK) {
            if (inputDone && zs.avail_in == 0 && written == 0) break;  // truncated stream
            continue;
        }
        throw FormatError(item + ": expected a valid zlib/gzip stream, found corrupt data (" +
                          (zs.msg ? std::string(zs.msg) : std::to_string(rc)) + ") after " +
                          std::to_string(produced) + " decompressed bytes");
    }
    if (!ended) {
        throw FormatError(item + ": expected " + std::to_string(expectedBytes) +
                          " bytes of decompressed voxel data, found a stream that ends after " +
                          std::to_string(produced) + " bytes (truncated)");
    }
    if (produced != expectedBytes) {
        throw FormatError(item + ": expected " + std::to_string(expectedBytes) +
                          " bytes of decompressed voxel data, found " + std::to_string(produced));
    }
    return out;
}

}  // namespace

namespace {

/// The compressed bytes of a stream at @p offset of @p path, at most @p maxCompressedBytes (all of
/// them when it is a header's size), handed out in chunks; the window [keepFrom, keepFrom +
/// keepCount) of the decompressed bytes is checked to lie inside @p expectedBytes.
class CompressedChunks {
  public:
    CompressedChunks(const fs::path& path, std::uint64_t offset, std::uint64_t maxCompressedBytes,
                     std::uint64_t expectedBytes, std::uint64_t keepFrom, std::uint64_t keepCount)
        : mBuffer(std::size_t{1} << 18) {
        if (keepFrom > expectedBytes || keepCount > expectedBytes - keepFrom) {
            throw ValueError(path.string() + ": expected a window inside the " +
                             std::to_string(expectedBytes) + " decompressed bytes, found bytes " +
                             std::to_string(keepFrom) + " + " + std::to_string(keepCount));
        }
        const std::uint64_t size = fileSize(path);
        if (offset > size) {
            throw FormatError(path.string() + ": expected compressed voxel data at byte " +
                              std::to_string(offset) + ", found a file of " + std::to_string(size) +
                              " bytes");
        }
        mRemaining = std::min(size - offset, maxCompressedBytes);
        if (maxCompressedBytes != std::numeric_limits<std::uint64_t>::max() &&
            mRemaining < maxCompressedBytes) {
            throw FormatError(path.string() + ": expected " + std::to_string(maxCompressedBytes) +
                              " bytes of compressed voxel data after the header, found " +
                              std::to_string(mRemaining));
        }
        mEnd = offset + mRemaining;
        mIn = openOrThrow(path);
        mIn.seekg(static_cast<std::streamoff>(offset));
    }

    /// The next chunk; empty at the end.
    std::span<const std::byte> operator()() {
        if (mRemaining == 0) return {};
        const auto want =
            static_cast<std::size_t>(std::min<std::uint64_t>(mRemaining, mBuffer.size()));
        mIn.read(reinterpret_cast<char*>(mBuffer.data()), static_cast<std::streamsize>(want));
        const auto got = static_cast<std::size_t>(std::max<std::streamsize>(mIn.gcount(), 0));
        mRemaining = got == 0 ? 0 : mRemaining - got;
        return {mBuffer.data(), got};
    }

    std::uint64_t remaining() const { return mRemaining; }
    std::uint64_t end() const { return mEnd; }

  private:
    std::ifstream mIn;
    std::vector<std::byte> mBuffer;
    std::uint64_t mRemaining = 0, mEnd = 0;
};

}  // namespace

std::vector<std::byte> inflateFileRange(const fs::path& path, std::uint64_t offset,
                                        std::uint64_t maxCompressedBytes,
                                        std::uint64_t expectedBytes) {
    return inflateFileWindow(path, offset, maxCompressedBytes, expectedBytes, 0, expectedBytes,
                             false);
}

std::vector<std::byte> inflateFileWindow(const fs::path& path, std::uint64_t offset,
                                         std::uint64_t maxCompressedBytes,
                                         std::uint64_t expectedBytes, std::uint64_t keepFrom,
                                         std::uint64_t keepCount, bool allowTrailing) {
    CompressedChunks next(path, offset, maxCompressedBytes, expectedBytes, keepFrom, keepCount);
    return inflateStream(next, expectedBytes, path.string(), keepFrom, keepCount, allowTrailing,
                         next.remaining());
}

namespace {

/// Records InflateIndex points: the last 32 KiB of output kept in a ring, copied at each block
/// boundary at least @p spacing bytes past the previous point, for output [keepFrom, keepEnd)
/// only: of the points before keepFrom, only the last is kept.
class IndexBuilder final : public InflateObserver {
  public:
    IndexBuilder(InflateIndex& index, std::uint64_t offset, std::uint64_t spacing,
                 std::uint64_t keepFrom, std::uint64_t keepEnd)
        : mIndex(index),
          mOffset(offset),
          mSpacing(spacing),
          mKeepFrom(keepFrom),
          mKeepEnd(keepEnd),
          mRing(kWindow) {}

    void output(std::span<const std::byte> bytes) override {
        // Only the last kWindow bytes of a long piece can end up in the ring.
        if (bytes.size() > kWindow) {
            mProduced += bytes.size() - kWindow;
            bytes = bytes.last(kWindow);
        }
        for (std::size_t done = 0; done < bytes.size();) {
            const std::size_t at = static_cast<std::size_t>(mProduced % kWindow);
            const std::size_t n = std::min(bytes.size() - done, kWindow - at);
            std::memcpy(mRing.data() + at, bytes.data() + done, n);
            done += n;
            mProduced += n;
        }
    }

    void boundary(std::uint64_t produced, std::uint64_t consumed, int bits) override {
        if (!mIndex.singleMember) return;  // the first member's points only
        if (mProduced != produced) {
            mIndex.singleMember = false;  // cannot happen; no random access rather than a wrong one
            return;
        }
        if (produced >= mKeepEnd) return;
        if (!mIndex.points.empty() && produced < mIndex.points.back().out + mSpacing) return;
        // A point before the window is replaced by a later one that is not inside it yet.
        if (!mIndex.points.empty() && mIndex.points.back().out < mKeepFrom && produced <= mKeepFrom)
            mIndex.points.pop_back();
        InflateIndex::Point p;
        p.out = produced;
        p.in = mOffset + consumed;
        p.bits = bits;
        const auto held = static_cast<std::size_t>(std::min<std::uint64_t>(produced, kWindow));
        p.window.resize(held);
        for (std::size_t i = 0; i < held; ++i)
            p.window[i] = mRing[static_cast<std::size_t>((produced - held + i) % kWindow)];
        mIndex.points.push_back(std::move(p));
    }

    void anotherMember() override { mIndex.singleMember = false; }

  private:
    static constexpr std::size_t kWindow = std::size_t{1} << 15;  // deflate's largest distance
    InflateIndex& mIndex;
    std::uint64_t mOffset, mSpacing, mKeepFrom, mKeepEnd;
    std::vector<std::byte> mRing;
    std::uint64_t mProduced = 0;
};

}  // namespace

InflateIndex indexFileStream(const fs::path& path, std::uint64_t offset,
                             std::uint64_t maxCompressedBytes, std::uint64_t expectedBytes,
                             std::uint64_t keepFrom, std::uint64_t keepCount, bool allowTrailing,
                             std::uint64_t spacing) {
    CompressedChunks next(path, offset, maxCompressedBytes, expectedBytes, keepFrom, keepCount);
    InflateIndex index;
    index.file = path;
    index.end = next.end();
    IndexBuilder builder(index, offset, std::max<std::uint64_t>(spacing, 1), keepFrom,
                         keepFrom + keepCount);
    (void)inflateStream(next, expectedBytes, path.string(), 0, 0, allowTrailing, next.remaining(),
                        &builder);
    return index;
}

void inflateAt(const InflateIndex& index, int fd, std::uint64_t from, std::span<std::byte> out) {
    const std::string item = index.file.string();
    if (!index.singleMember || index.points.empty()) {
        throw Error(item + ": expected an index of a single-member stream, found none");
    }
    // The last point at or before @p from.
    auto it =
        std::upper_bound(index.points.begin(), index.points.end(), from,
                         [](std::uint64_t v, const InflateIndex::Point& p) { return v < p.out; });
    if (it == index.points.begin()) throw Error(item + ": expected an index point before a byte");
    const InflateIndex::Point& p = *std::prev(it);

    z_stream zs{};
    if (inflateInit2(&zs, -15) != Z_OK) throw Error(item + ": expected zlib to initialise");
    struct Guard {
        z_stream* s;
        ~Guard() { inflateEnd(s); }
    } guard{&zs};
    std::vector<std::byte> input(std::size_t{1} << 16), skip(std::size_t{1} << 16);
    std::uint64_t at = p.in;  // next compressed byte to read
    const auto readInput = [&](std::byte* dst, std::size_t want) -> std::size_t {
        want = static_cast<std::size_t>(std::min<std::uint64_t>(want, index.end - at));
        std::size_t done = 0;
        while (done < want) {
            const ssize_t got = ::pread(fd, dst + done, want - done, static_cast<off_t>(at + done));
            if (got < 0 && errno == EINTR) continue;
            if (got <= 0) {
                throw FormatError(item + ": expected compressed bytes at byte " +
                                  std::to_string(at + done) + ", found " +
                                  (got < 0 ? std::string("a read error: ") + std::strerror(errno)
                                           : std::string("the end of the file (it shrank)")));
            }
            done += static_cast<std::size_t>(got);
        }
        at += done;
        return done;
    };
    if (p.bits > 0) {
        // The point starts inside the byte before p.in: its high bits are the next block's.
        std::byte last{};
        at = p.in - 1;
        (void)readInput(&last, 1);
        inflatePrime(&zs, p.bits,
                     static_cast<int>(std::to_integer<unsigned>(last) >> (8 - p.bits)));
    }
    if (!p.window.empty() &&
        inflateSetDictionary(&zs, reinterpret_cast<const Bytef*>(p.window.data()),
                             static_cast<uInt>(p.window.size())) != Z_OK) {
        throw Error(item + ": expected zlib to take the index's window");
    }
    std::uint64_t produced = p.out;
    std::size_t filled = 0;
    while (filled < out.size()) {
        if (zs.avail_in == 0) {
            const std::size_t got = readInput(input.data(), input.size());
            zs.next_in = reinterpret_cast<Bytef*>(input.data());
            zs.avail_in = static_cast<uInt>(got);
        }
        std::byte* dst;
        std::size_t room;
        if (produced < from) {
            dst = skip.data();
            room = static_cast<std::size_t>(std::min<std::uint64_t>(skip.size(), from - produced));
        } else {
            dst = out.data() + filled;
            room = std::min<std::size_t>(out.size() - filled, std::size_t{1} << 30);
        }
        zs.next_out = reinterpret_cast<Bytef*>(dst);
        zs.avail_out = static_cast<uInt>(room);
        const int rc = inflate(&zs, Z_NO_FLUSH);
        const std::size_t written = room - zs.avail_out;
        if (produced >= from) filled += written;
        produced += written;
        if (filled == out.size()) break;
        if (rc == Z_STREAM_END || (rc == Z_BUF_ERROR && zs.avail_in == 0 && at >= index.end) ||
            (rc != Z_OK && rc != Z_BUF_ERROR)) {
            throw FormatError(item + ": expected " + std::to_string(out.size()) +
                              " decompressed bytes at byte " + std::to_string(from) +
                              " of the stream, found " + std::to_string(filled) + " (" +
                              (zs.msg ? std::string(zs.msg) : std::to_string(rc)) + ")");
        }
    }
}

std::vector<std::byte> inflateBytes(std::span<const std::byte> compressed,
                                    std::uint64_t expectedBytes, const std::string& item) {
    bool given = false;
    auto next = [&]() -> std::span<const std::byte> {
        if (given) return {};
        given = true;
        // zlib takes at most 4 GiB per call; hand larger inputs over in pieces.
        return compressed.first(std::min<std::size_t>(compressed.size(), std::size_t{1} << 30));
    };
    if (compressed.size() > (std::size_t{1} << 30)) {
        std::size_t pos = 0;
        auto chunked = [&]() -> std::span<const std::byte> {
            const std::size_t n =
                std::min<std::size_t>(compressed.size() - pos, std::size_t{1} << 30);
            std::span<const std::byte> s = compressed.subspan(pos, n);
            pos += n;
            return s;
        };
        return inflateStream(chunked, expectedBytes, item, 0, expectedBytes, false,
                             compressed.size());
    }
    return inflateStream(next, expectedBytes, item, 0, expectedBytes, false, compressed.size());
}

std::vector<float> readAsciiValues(const fs::path& path, std::uint64_t offset,
                                   std::uint64_t count) {
    const std::uint64_t size = fileSize(path);
    const std::uint64_t available = size > offset ? size - offset : 0;
    // Each number takes at least one character and one separator (the last may end the file).
    if (count > 0 && available < 2 * count - 1) {
        throw FormatError(path.string() + ": expected " + std::to_string(count) +
                          " numbers of ASCII voxel data after the header, found only " +
                          std::to_string(available) + " bytes");
    }
    std::vector<std::byte> raw = readFileRange(path, offset, available);
    const char* p = reinterpret_cast<const char*>(raw.data());
    const char* end = p + raw.size();
    std::vector<float> values;
    values.reserve(static_cast<std::size_t>(count));
    auto isSep = [](char c) {
        return std::isspace(static_cast<unsigned char>(c)) != 0 || c == ',';
    };
    while (values.size() < count) {
        while (p < end && isSep(*p)) ++p;
        if (p == end) break;
        double v = 0;
        const auto res = std::from_chars(p, end, v);
        if (res.ec != std::errc() && res.ec != std::errc::result_out_of_range) {
            const char* tokEnd = p;
            while (tokEnd < end && !isSep(*tokEnd) && tokEnd - p < 20) ++tokEnd;
            throw FormatError(path.string() + ": expected a number as ASCII voxel value " +
                              std::to_string(values.size()) + ", found '" + std::string(p, tokEnd) +
                              "'");
        }
        // Out of double's range: from_chars leaves v unset; strtod gives +-inf or 0 for it.
        if (res.ec == std::errc::result_out_of_range)
            v = std::strtod(std::string(p, res.ptr).c_str(), nullptr);
        values.push_back(saturatingFloat(v));
        p = res.ptr;
    }
    if (values.size() < count) {
        throw FormatError(path.string() + ": expected " + std::to_string(count) +
                          " ASCII voxel values, found " + std::to_string(values.size()));
    }
    return values;
}

std::uint64_t skipLines(const fs::path& path, std::uint64_t offset, std::int64_t lines) {
    if (lines <= 0) return offset;
    std::ifstream in = openOrThrow(path);
    in.seekg(static_cast<std::streamoff>(offset));
    std::uint64_t pos = offset;
    std::int64_t seen = 0;
    char buf[4096];
    while (seen < lines) {
        in.read(buf, sizeof buf);
        const std::streamsize got = in.gcount();
        if (got <= 0) {
            throw FormatError(path.string() + ": expected " + std::to_string(lines) +
                              " lines to skip before the voxel data, found " +
                              std::to_string(seen));
        }
        for (std::streamsize i = 0; i < got; ++i) {
            if (buf[i] == '\n' && ++seen == lines) return pos + static_cast<std::uint64_t>(i) + 1;
        }
        pos += static_cast<std::uint64_t>(got);
    }
    return pos;
}

}  // namespace palp::volume
