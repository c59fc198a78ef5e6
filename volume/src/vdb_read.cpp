// Reading a .vdb file's grids through a stream over a read-only memory map.
#include "vdb_read.h"

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

/// Thrown by MemoryBuf when a read goes past the end of the bytes.
struct PastTheEnd {};

/// A read-only, seekable stream buffer over bytes in memory: tellg() and seekg() are pointer
/// arithmetic, reads are copies, and a read past the end throws PastTheEnd (OpenVDB does not
/// check its stream between reads: counts read from a file cut short could drive it around a
/// loop for a long time).
class MemoryBuf final : public std::streambuf {
  public:
    MemoryBuf(const char* data, std::size_t size) {
        char* p = const_cast<char*>(data);  // get area only: never written through
        setg(p, p, p + size);
    }

  protected:
    int_type underflow() override {
        if (gptr() < egptr()) return traits_type::to_int_type(*gptr());
        throw PastTheEnd{};
    }
    pos_type seekoff(off_type off, std::ios_base::seekdir dir,
                     std::ios_base::openmode which) override {
        if (!(which & std::ios_base::in)) return pos_type(off_type(-1));
        const off_type base = dir == std::ios_base::beg   ? 0
                              : dir == std::ios_base::cur ? gptr() - eback()
                                                          : egptr() - eback();
        const off_type to = base + off;
        if (to < 0 || to > egptr() - eback()) return pos_type(off_type(-1));
        setg(eback(), eback() + to, egptr());
        return pos_type(to);
    }
    pos_type seekpos(pos_type pos, std::ios_base::openmode which) override {
        return seekoff(off_type(pos), std::ios_base::beg, which);
    }
};

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
    in.exceptions(std::ios::badbit);  // the stream rethrows what its buffer throws
    const auto truncated = [&] {
        return FormatError(path.string() + ": expected a complete OpenVDB file, found it ends " +
                           "early (" + std::to_string(file.size()) +
                           " bytes; truncated or damaged)");
    };
    openvdb::GridPtrVecPtr grids;
    try {
        openvdb::io::Stream stream(in, /*delayLoad=*/false);
        grids = stream.getGrids();
    } catch (const PastTheEnd&) {
        throw truncated();
    }
    // Without OpenVDB reading past the end, a short read still leaves the stream failed.
    if (in.fail()) throw truncated();
    return grids;
}

}  // namespace palp::volume::detail
