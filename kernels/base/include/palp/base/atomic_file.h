#pragma once
/// @file
/// Writing a file so that a reader (or a failure) never sees it half-written: the content goes
/// to a temporary file beside the target, which is renamed over the target only when complete.
/// Every palp writer (volumes, DICOM series, traces, maps, device logs) goes through this.

#include <cstddef>
#include <filesystem>
#include <string>

namespace palp {

/// A temporary file beside @p path that commit() renames into place. If commit() is never
/// reached (an exception, an early return), the destructor removes the temporary, so a failed
/// write leaves nothing behind and an existing file at @p path untouched.
///
/// Usage: `AtomicFile f(path, "trace"); write to f.tempPath(); f.commit();`
/// @par Threading
/// One thread uses an instance; temporary names are unique per process, instance and call.
class AtomicFile {
  public:
    /// @p what names the content in error messages (e.g. "trace", "volume").
    /// @throw IoError (naming @p path) when @p path is a directory (an existing one, or a path
    /// ending in '/', '.' or '..') or empty, or when the directory it is to be written in does
    /// not exist; nothing is created then.
    AtomicFile(std::filesystem::path path, std::string what);
    ~AtomicFile();
    AtomicFile(const AtomicFile&) = delete;
    AtomicFile& operator=(const AtomicFile&) = delete;

    /// Where to write the content (a hidden file in the target's directory).
    const std::filesystem::path& tempPath() const noexcept { return mTemp; }
    /// The final path.
    const std::filesystem::path& path() const noexcept { return mPath; }

    /// Renames the temporary over path(). @throw IoError (temporary removed when this object is
    /// destroyed) when it fails, with rename()'s reason, or "found a directory" when path() has
    /// become one.
    void commit();

  private:
    std::filesystem::path mPath;
    std::filesystem::path mTemp;
    std::string mWhat;
    bool mCommitted = false;
};

/// Writes @p size bytes of @p data to @p path through an AtomicFile.
/// @throw IoError naming the file and the failure.
void writeFileAtomically(const std::filesystem::path& path, const std::string& what,
                         const void* data, std::size_t size);

}  // namespace palp
