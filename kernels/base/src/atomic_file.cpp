#include "palp/base/atomic_file.h"

#include <unistd.h>

#include <atomic>
#include <fstream>

#include "palp/base/error.h"

namespace palp {

namespace fs = std::filesystem;

namespace {
std::atomic<unsigned long> gSerial{0};  // distinguishes temporaries of one process
}  // namespace

AtomicFile::AtomicFile(fs::path path, std::string what)
    : mPath(std::move(path)), mWhat(std::move(what)) {
    const fs::path dir = mPath.has_parent_path() ? mPath.parent_path() : fs::path(".");
    std::error_code ec;
    // A directory as the target (`-o DIR`, `-o DIR/`, `.`) is refused before anything is
    // written: rename() would fail only after the whole content was written, with an errno
    // that names the wrong thing ("Not a directory" for DIR/, "Device or resource busy" for .).
    const fs::path leaf = mPath.filename();
    if (mPath.empty() || leaf.empty() || leaf == "." || leaf == ".." ||
        fs::is_directory(mPath, ec)) {
        throw IoError((mPath.empty() ? std::string("''") : mPath.string()) +
                      ": expected a file name for the " + mWhat + ", found " +
                      (mPath.empty() ? std::string("an empty path") : "a directory"));
    }
    if (!fs::is_directory(dir, ec)) {
        throw IoError(mPath.string() + ": expected an existing directory '" + dir.string() +
                      "' for the " + mWhat + ", found none");
    }
    // Built by appending: GCC 12 reports a false -Wrestrict for "." + std::string.
    std::string name(1, '.');
    name += mPath.filename().string();
    name += ".tmp" + std::to_string(::getpid()) + "-" +
            std::to_string(gSerial.fetch_add(1, std::memory_order_relaxed));
    mTemp = dir / name;
}

AtomicFile::~AtomicFile() {
    if (mCommitted) return;
    std::error_code ignored;
    fs::remove(mTemp, ignored);
}

void AtomicFile::commit() {
    std::error_code ec;
    // The target may have become a directory since construction; say so rather than errno.
    if (fs::is_directory(mPath, ec)) {
        throw IoError(mPath.string() + ": expected a file name for the " + mWhat +
                      ", found a directory (the " + mWhat + " was not written)");
    }
    ec.clear();
    fs::rename(mTemp, mPath, ec);
    if (ec) {
        // ec carries rename()'s errno; an error code of 0 would print "Success".
        const std::string reason = ec.value() != 0 ? ec.message() : "an unknown error";
        throw IoError(mPath.string() + ": could not rename the finished " + mWhat +
                      " into place: " + reason);
    }
    mCommitted = true;
}

void writeFileAtomically(const fs::path& path, const std::string& what, const void* data,
                         std::size_t size) {
    AtomicFile file(path, what);
    {
        std::ofstream out(file.tempPath(), std::ios::binary | std::ios::trunc);
        if (!out) throw IoError(path.string() + ": cannot open a temporary file for the " + what);
        out.write(static_cast<const char*>(data), static_cast<std::streamsize>(size));
        out.close();
        if (!out) {
            throw IoError(path.string() + ": expected to write " + std::to_string(size) +
                          " bytes of the " + what + ", the write failed");
        }
    }
    file.commit();
}

}  // namespace palp
