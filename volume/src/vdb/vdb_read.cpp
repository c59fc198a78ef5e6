// Reading a .vdb file's grids through a stream over a read-only memory map.
#include "vdb/vdb_read.h"

#include <fcntl.h>
#include <openvdb/io/Stream.h>
#include <sys/mman.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>
#include <istream>
#include <streambuf>
#include <string>

#include "palp/base/error.h"

namespace palp::volume::detail {

namespace {

/// A read-only, seekable stream buffer over bytes in memory: tellg() and seekg() are pointer
/// arithmetic and reads are copies. Past the end it reads zeros and remembers that it did.
/// OpenVDB does not check its stream between reads: from a failed stream, counts keep whatever
/// the last read left (a file cut in its metadata made OpenVDB's own reader spin forever), and
/// throwing out of OpenVDB's reads leaks the node being read (it holds it by a raw pointer).
/// Zeros end every loop at once (no tiles, no children, empty masks), and the caller refuses
/// the file afterwards.
class MemoryBuf final : public std::streambuf {
  public:
    MemoryBuf(const char* data, std::size_t size)
        : mData(const_cast<char*>(data)),  // get area only: never written through
          mSize(static_cast<off_type>(size)) {
        setg(mData, mData, mData + mSize);
    }

    /// Whether a read or a seek went past the end of the bytes.
    bool pastTheEnd() const { return mPastTheEnd; }

  protected:
    int_type underflow() override {
        if (gptr() < egptr()) return traits_type::to_int_type(*gptr());
        zerosFrom(position());
        return traits_type::to_int_type(*gptr());
    }
    pos_type seekoff(off_type off, std::ios_base::seekdir dir,
                     std::ios_base::openmode which) override {
        if (!(which & std::ios_base::in)) return pos_type(off_type(-1));
        const off_type base = dir == std::ios_base::beg   ? 0
                              : dir == std::ios_base::cur ? position()
                                                          : mSize;
        const off_type to = base + off;
        if (to < 0) return pos_type(off_type(-1));
        if (to <= mSize) {
            setg(mData, mData + to, mData + mSize);
        } else {
            zerosFrom(to);
        }
        return pos_type(to);
    }
    pos_type seekpos(pos_type pos, std::ios_base::openmode which) override {
        return seekoff(off_type(pos), std::ios_base::beg, which);
    }

  private:
    /// The stream position of the next byte.
    off_type position() const {
        return eback() == sZeros ? mZerosAt + (gptr() - eback()) : gptr() - eback();
    }
    /// Serves zeros from stream position @p at on.
    void zerosFrom(off_type at) {
        mPastTheEnd = true;
        mZerosAt = at;
        setg(sZeros, sZeros, sZeros + sizeof(sZeros));
    }

    static char sZeros[1 << 16];  // read only: the get area is never written through
    char* mData;
    off_type mSize;
    off_type mZerosAt = 0;
    bool mPastTheEnd = false;
};

char MemoryBuf::sZeros[1 << 16] = {};

/// A file mapped read-only for the lifetime of the object.
class MappedFile {
  public:
    explicit MappedFile(const std::filesystem::path& path) {
        const int fd = ::open(path.c_str(), O_RDONLY | O_CLOEXEC);
        if (fd < 0) fail(path, "open");
        struct stat st {};
        if (::fstat(fd, &st) != 0) {
            const int e = errno;
            ::close(fd);
            errno = e;
            fail(path, "stat");
        }
        mSize = static_cast<std::size_t>(st.st_size);
        if (mSize > 0) {
            void* p = ::mmap(nullptr, mSize, PROT_READ, MAP_PRIVATE | MAP_POPULATE, fd, 0);
            if (p == MAP_FAILED) {
                const int e = errno;
                ::close(fd);
                errno = e;
                fail(path, "map");
            }
            mData = static_cast<const char*>(p);
            ::madvise(p, mSize, MADV_SEQUENTIAL);
        }
        ::close(fd);  // the mapping keeps the file
    }
    ~MappedFile() {
        if (mData) ::munmap(const_cast<char*>(mData), mSize);
    }
    MappedFile(const MappedFile&) = delete;
    MappedFile& operator=(const MappedFile&) = delete;

    const char* data() const { return mData; }
    std::size_t size() const { return mSize; }

  private:
    [[noreturn]] static void fail(const std::filesystem::path& path, const char* what) {
        throw IoError(path.string() + ": expected a readable file, found that " + what +
                      " failed: " + std::strerror(errno));
    }

    const char* mData = nullptr;
    std::size_t mSize = 0;
};

}  // namespace

openvdb::GridPtrVecPtr readGridsMapped(const std::filesystem::path& path) {
    const MappedFile file(path);
    MemoryBuf buffer(file.data(), file.size());
    std::istream in(&buffer);
    const auto truncated = [&] {
        return FormatError(path.string() + ": expected a complete OpenVDB file, found it ends " +
                           "early (" + std::to_string(file.size()) +
                           " bytes; truncated or damaged)");
    };
    openvdb::GridPtrVecPtr grids;
    try {
        openvdb::io::Stream stream(in, /*delayLoad=*/false);
        grids = stream.getGrids();
    } catch (...) {
        // What OpenVDB made of the zeros past the end (an unregistered grid type "", an empty
        // metadata name) is not the file's fault: its end is.
        if (buffer.pastTheEnd()) throw truncated();
        throw;
    }
    if (buffer.pastTheEnd() || in.fail()) throw truncated();
    return grids;
}

}  // namespace palp::volume::detail
