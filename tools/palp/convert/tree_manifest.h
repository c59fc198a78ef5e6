#pragma once
/// @file
/// The manifest of `palp convert-tree`: one row per series (input, output, status, message),
/// written as a tab-separated table through an atomic rename after every series, so that a
/// reader (or a resumed run) sees either the previous manifest or the next one, never a
/// half-written one; and the merge of the shards' manifests into one.
///
/// Format (docs/volumes.md, "Converting a whole archive"): `#` lines first (`# palp
/// convert-tree manifest 1`, `# options ...`, `# shard all|i/N`, `# series K of T`), then a
/// header line and one row per series, sorted by output. Text fields escape backslash, tab,
/// newline and carriage return as `\\`, `\t`, `\n`, `\r`.

#include <cstdint>
#include <filesystem>
#include <string>
#include <vector>

namespace palp::tool {

/// What became of one series.
enum class TreeStatus {
    Done,     ///< converted; the output is complete
    Refused,  ///< the input cannot be converted (damaged, inconsistent, unsupported): message
    Failed,   ///< the conversion could not finish (output not writable, out of memory, ...)
    Skipped,  ///< nothing to convert: a DICOM series without images (reports, key objects)
};

/// "done", "refused", "failed", "skipped".
const char* statusName(TreeStatus s);

/// One series of a manifest.
struct ManifestRow {
    std::string output;  ///< the .vdb, relative to the output folder ('/'-separated)
    TreeStatus status = TreeStatus::Failed;
    std::string input;      ///< the series' folder or the file, relative to the input folder
    std::string seriesUid;  ///< DICOM SeriesInstanceUID; empty for other formats
    std::string format;     ///< "DICOM", "NIfTI", "NRRD", "MetaImage"
    std::uint64_t sourceFiles = 0;  ///< files read for the series
    std::uint64_t sourceBytes = 0;  ///< their total size in bytes
    std::uint64_t bytes = 0;        ///< the output's size in bytes (done only)
    std::string message;            ///< done: what was written; otherwise why not
};

/// A manifest: its run's options and shard, and its rows sorted by output.
struct Manifest {
    std::string options;        ///< describeConvertFlags() of the run
    std::string shard = "all";  ///< "all" or "i/N"
    std::uint64_t series = 0;   ///< series the run was to convert (its shard's)
    std::uint64_t found = 0;    ///< series found in the whole tree
    std::vector<ManifestRow> rows;
};

/// "manifest.tsv" (@p count 0) or "manifest.shard-I-of-N.tsv".
std::string manifestName(std::int64_t index, std::int64_t count);

/// Writes @p m to @p path through palp::AtomicFile (temporary file, then rename).
/// @throw IoError naming @p path.
void writeManifest(const std::filesystem::path& path, const Manifest& m);

/// Reads a manifest written by writeManifest().
/// @throw IoError (unreadable), FormatError naming the file and line (not a manifest, a row
/// with the wrong number of fields, a status or number that is not one).
Manifest readManifest(const std::filesystem::path& path);

/// The manifests in @p outDir (manifest.tsv and manifest.shard-*-of-*.tsv), sorted by name.
std::vector<std::filesystem::path> listManifests(const std::filesystem::path& outDir);

/// Whether @p row is done and its output under @p outDir is there, of the size the row gives,
/// and an OpenVDB file (its magic bytes); @p why says what is wrong otherwise.
bool outputIsValid(const std::filesystem::path& outDir, const ManifestRow& row, std::string& why);

/// `palp convert-tree merge OUT_DIR`: the shard manifests of one shard count N in @p outDir,
/// checked (all N there, one options line, each shard complete, every done output valid) and
/// merged into OUT_DIR/manifest.tsv. Prints a summary unless @p quiet.
/// @return 0 when every series is done, 1 when one was refused or a shard is incomplete or an
/// output invalid, 2 when one failed.
/// @throw IoError, FormatError naming the manifest; ValueError when there is no shard manifest,
/// or several shard counts, or shards of different options.
int mergeManifests(const std::filesystem::path& outDir, bool quiet);

}  // namespace palp::tool
