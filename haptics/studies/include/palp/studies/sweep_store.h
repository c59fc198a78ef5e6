#pragma once
/// @file
/// Where a sweep's results live (docs/error_analysis.md): a directory with `manifest.json` (the
/// sweep's id, ranges, design, seed and sample count) and `shards/`, one CSV per computed range
/// of samples, each written atomically (temporary + rename). A shard file is
///
///     # palp-sweep-shard 1 sweep=<id> first=<i> end=<j>
///     <the table's header>
///     <one row per sample i..j-1, in order>
///     # end rows=<j-i> fnv1a64=<hash of the rows' bytes>
///
/// beside `<shard>.timing.csv` (host and wall times, which differ from run to run and so stay
/// out of the table). Merging checks every shard against the manifest and writes one table
/// whose bytes do not depend on how the samples were split.

#include <cstdint>
#include <filesystem>
#include <functional>
#include <string>
#include <vector>

#include "palp/base/validate.h"
#include "palp/studies/sweep_design.h"
#include "palp/studies/sweep_run.h"

namespace palp::haptics {

/// Samples [first, end).
struct SampleRange {
    std::int64_t first = 0;
    std::int64_t end = 0;
    std::int64_t size() const { return end - first; }
    bool operator==(const SampleRange&) const = default;
};

/// Shard @p i of @p n (0 <= i < n): a contiguous range of whole groups (so that a group's
/// reference is computed once), the groups split as evenly as integers allow. Empty when
/// n exceeds the number of groups and i has none.
/// @throw palp::ValueError for n < 1 or i outside [0, n).
SampleRange shardRange(const SweepSpec& spec, std::int64_t i, std::int64_t n);

/// Parses "i/n" as --shard takes it (palp/base/validate.h).
using palp::parseShard;

/// Writes `manifest.json` of @p spec into @p dir (created if missing), or checks the one there.
/// @throw palp::ValueError when @p dir holds a manifest of another sweep (naming the file and
/// the fields that differ), palp::FormatError when it is not a manifest, palp::IoError on IO.
void prepareSweepDir(const std::filesystem::path& dir, const SweepSpec& spec);
/// Reads the manifest of @p dir back into a spec (the ranges re-parsed from their copy).
/// @throw palp::IoError, palp::FormatError naming the file and field.
SweepSpec readSweepManifest(const std::filesystem::path& dir);

/// A shard found in a sweep directory.
struct ShardFile {
    std::filesystem::path path;
    SampleRange range;
};
/// The shards of @p dir that belong to @p spec and are intact. A shard of another sweep is an
/// error (palp::ValueError naming the file and its 'sweep' field); a corrupt one (truncated,
/// bad checksum, bad rows) is an error too when @p strict, else it is renamed to
/// `<name>.corrupt` and skipped (so --resume recomputes it) with a line to @p warn.
std::vector<ShardFile> listShards(const std::filesystem::path& dir, const SweepSpec& spec,
                                  bool strict,
                                  const std::function<void(const std::string&)>& warn = {});

/// The parts of @p want that no range of @p have covers, in order.
std::vector<SampleRange> missingRanges(const SampleRange& want, const std::vector<ShardFile>& have);

/// Writes the rows of @p results (samples results[0].index .. +size, in order) as a shard of
/// @p spec in @p dir, atomically, with its timing file. @p host names the machine.
void writeShard(const std::filesystem::path& dir, const SweepSpec& spec,
                const std::vector<SweepSampleResult>& results, const std::string& host);

/// Runs the samples of @p range with @p runner and writes them as shards of at most
/// @p chunk samples (chunk boundaries on multiples of @p chunk from range.first), calling
/// @p progress after each sample. Returns the results' total wall time, s.
double runRange(const std::filesystem::path& dir, SweepRunner& runner, const SampleRange& range,
                std::int64_t chunk, const std::string& host,
                const std::function<void(std::int64_t)>& progress = {});

/// Merges the shards of @p dir into @p table (CSV) and its sidecar (table with extension
/// ".json": columns, units, roles, palp version, parameters, seed, machines) plus
/// "<stem>.timings.csv". Every shard must belong to the manifest's sweep, be intact, and the
/// shards must cover every sample exactly once; otherwise nothing is written and the error
/// names the file and field (palp::ValueError / palp::FormatError).
/// @return the number of rows written.
std::int64_t mergeSweep(const std::filesystem::path& dir, const std::filesystem::path& table);

/// This machine's host name and CPU model, for the sidecar and the timings.
std::string sweepHostName();
std::string sweepCpuModel();

}  // namespace palp::haptics
