// palp convert-tree: every series under a folder converted in one process, with a manifest that
// is rewritten atomically after each series, --resume, --shard i/N for job arrays, and
// `palp convert-tree merge OUT_DIR` for the shards' manifests.
#include <algorithm>
#include <cstdio>
#include <filesystem>
#include <map>
#include <new>
#include <string>
#include <utility>
#include <vector>

#include "../batch_heap.h"
#include "../commands.h"
#include "../progress.h"
#include "../volume_flags.h"
#include "convert_flags.h"
#include "palp/base/error.h"
#include "palp/base/validate.h"
#include "palp/volume/find_scans.h"
#include "tree_manifest.h"

namespace palp::tool {

namespace fs = std::filesystem;

namespace {

struct TreeArgs {
    std::string in, out;
    ConvertFlags flags;
    bool resume = false;
    std::string shard;
    std::string mergeDir;
};

/// A found scan with the names the tree gives it.
struct PlannedScan {
    const volume::FoundScan* scan = nullptr;
    std::string output;     // relative to the output folder
    std::string input;      // relative to the input folder
    std::string collision;  // another scan's input when both derive this output name
};

/// @p text with every character outside [A-Za-z0-9._-] replaced by '_', at most 200 long (a
/// file name from a SeriesInstanceUID, which should hold digits and dots only).
std::string safeName(const std::string& text) {
    std::string s = text.substr(0, 200);
    for (char& c : s) {
        const bool ok = (c >= '0' && c <= '9') || (c >= 'a' && c <= 'z') ||
                        (c >= 'A' && c <= 'Z') || c == '.' || c == '-' || c == '_';
        if (!ok) c = '_';
    }
    return s;
}

/// @p p relative to @p root, '/'-separated; "." for @p root itself.
std::string relativeTo(const fs::path& p, const fs::path& root) {
    const fs::path rel = p.lexically_relative(root);
    return rel.empty() ? std::string(".") : rel.generic_string();
}

/// The output name of @p s (docs/volumes.md, "Converting a whole archive"): a file's path
/// under the input folder with ".vdb" appended; a DICOM series' folder (the deepest holding
/// all its files) and its SeriesInstanceUID (or "no-series-uid", or "unreadable-dicom" for
/// files whose series cannot be read) with ".vdb".
std::string outputName(const volume::FoundScan& s, const fs::path& root) {
    if (s.format != volume::Format::Dicom) return relativeTo(s.files.front(), root) + ".vdb";
    const std::string folder = relativeTo(s.folder, root);
    const std::string name = !s.seriesUid.empty() ? safeName(s.seriesUid)
                             : s.unreadable       ? std::string("unreadable-dicom")
                                                  : std::string("no-series-uid");
    return (folder == "." ? std::string() : folder + "/") + name + ".vdb";
}

/// Every scan named, sorted by output (then input): a scan's place in this list is its stable
/// index, which --shard takes modulo N.
std::vector<PlannedScan> planTree(const std::vector<volume::FoundScan>& found,
                                  const fs::path& root) {
    std::vector<PlannedScan> plan;
    plan.reserve(found.size());
    for (const volume::FoundScan& s : found) {
        PlannedScan p;
        p.scan = &s;
        p.output = outputName(s, root);
        p.input = relativeTo(s.format == volume::Format::Dicom ? s.folder : s.files.front(), root);
        plan.push_back(std::move(p));
    }
    std::sort(plan.begin(), plan.end(), [](const PlannedScan& a, const PlannedScan& b) {
        return a.output != b.output ? a.output < b.output : a.input < b.input;
    });
    for (std::size_t i = 1; i < plan.size(); ++i) {
        if (plan[i].output != plan[i - 1].output) continue;
        plan[i].collision = plan[i - 1].input;
        if (plan[i - 1].collision.empty()) plan[i - 1].collision = plan[i].input;
    }
    return plan;
}

/// The row of @p p before its conversion: input, series, format and source size.
ManifestRow baseRow(const PlannedScan& p) {
    ManifestRow r;
    r.output = p.output;
    r.input = p.input;
    r.seriesUid = p.scan->seriesUid;
    r.format = volume::formatName(p.scan->format);
    r.sourceFiles = p.scan->files.size();
    for (const fs::path& f : p.scan->files) {
        std::error_code ec;
        const std::uintmax_t size = fs::file_size(f, ec);
        if (!ec) r.sourceBytes += size;
    }
    return r;
}

/// Converts @p p into @p outDir / p.output (through an atomic rename: complete or absent) and
/// says what became of it. Never throws for the series' own errors.
ManifestRow convertOne(const PlannedScan& p, const fs::path& outDir, const ConvertFlags& flags,
                       const std::string& label) {
    ManifestRow r = baseRow(p);
    const volume::FoundScan& s = *p.scan;
    if (!p.collision.empty()) {
        r.status = TreeStatus::Refused;
        r.message = "output name " + p.output + " is also that of the input " + p.collision +
                    " (a file named like a series UID); rename one of them";
        return r;
    }
    if (s.format == volume::Format::Dicom && s.imageCount == 0 && !s.unreadable) {
        r.status = TreeStatus::Skipped;
        r.message = "no images: " + std::to_string(s.files.size()) +
                    " DICOM files without Rows, Columns and Pixel Data (modality " +
                    (s.modality.empty() ? std::string("unknown") : s.modality) + ")";
        return r;
    }
    try {
        volume::LoadOptions opt = loadOptions(flags);
        if (s.format == volume::Format::Dicom) opt.seriesUid = s.seriesUid;
        opt.resample.progress = progressLine(label);
        if (opt.resample.progress) opt.resample.progress(0.0);
        const fs::path out = outDir / p.output;
        std::error_code ec;
        fs::create_directories(out.parent_path(), ec);
        if (!fs::is_directory(out.parent_path())) {
            throw IoError(out.parent_path().string() +
                          ": expected a folder for the output, could not create it" +
                          (ec ? ": " + ec.message() : std::string()));
        }
        const volume::ConvertSummary vol =
            withVolumeFlags([&] { return volume::convert(s.files, out, opt, saveOptions(flags)); });
        r.bytes = fs::file_size(out);
        r.status = TreeStatus::Done;
        r.message = describeVolume(vol) + "; " + describeBackground(vol);
    } catch (const FormatError& e) {
        r.status = TreeStatus::Refused;
        r.message = e.what();
    } catch (const ValueError& e) {
        r.status = TreeStatus::Refused;
        r.message = e.what();
    } catch (const IoError& e) {
        r.status = TreeStatus::Failed;
        r.message = e.what();
    } catch (const std::bad_alloc&) {
        r.status = TreeStatus::Failed;
        r.message = "out of memory";
    } catch (const std::exception& e) {
        r.status = TreeStatus::Failed;
        r.message = std::string("internal error: ") + e.what();
    }
    return r;
}

using RowKey = std::pair<std::string, std::string>;  // output, input

/// The done rows of every manifest in @p outDir (a shard's or the whole tree's), checked to
/// come from a run with @p options.
/// @throw ValueError naming the manifest whose options differ.
std::map<RowKey, ManifestRow> doneBefore(const fs::path& outDir, const std::string& options) {
    std::map<RowKey, ManifestRow> done;
    for (const fs::path& path : listManifests(outDir)) {
        const Manifest m = readManifest(path);
        if (m.options != options) {
            throw ValueError("--resume: " + path.string() + ": expected a manifest of options '" +
                             options + "', found '" + m.options +
                             "' (resume with the same flags, or convert into a new folder)");
        }
        for (const ManifestRow& r : m.rows)
            if (r.status == TreeStatus::Done) done.emplace(RowKey{r.output, r.input}, r);
    }
    return done;
}

/// Whether @p before (an earlier run's done row) still stands for @p now (the same series, of
/// the same files and size, its output complete).
bool stillDone(const ManifestRow& before, const ManifestRow& now, const fs::path& outDir) {
    std::string why;
    return before.seriesUid == now.seriesUid && before.format == now.format &&
           before.sourceFiles == now.sourceFiles && before.sourceBytes == now.sourceBytes &&
           outputIsValid(outDir, before, why);
}

/// "palp convert-tree 12/100 INPUT" cut or padded to a fixed width, so that a terminal's line
/// is redrawn in place.
std::string progressLabel(std::size_t k, std::size_t n, const std::string& input) {
    std::string label = "palp convert-tree " + std::to_string(k) + "/" + std::to_string(n) + " ";
    constexpr std::size_t kWidth = 72;
    std::string name = input;
    if (label.size() + name.size() > kWidth) {
        const std::size_t keep = kWidth > label.size() + 3 ? kWidth - label.size() - 3 : 0;
        name = "..." + name.substr(name.size() - std::min(keep, name.size()));
    }
    label += name;
    label.resize(std::max(label.size(), kWidth), ' ');
    return label;
}

void insertRow(std::vector<ManifestRow>& rows, ManifestRow row) {
    const auto at = std::lower_bound(
        rows.begin(), rows.end(), row, [](const ManifestRow& a, const ManifestRow& b) {
            return RowKey{a.output, a.input} < RowKey{b.output, b.input};
        });
    rows.insert(at, std::move(row));
}

int runTree(const TreeArgs& a) {
    batchHeap();
    if (a.in.empty() || a.out.empty()) {
        throw ValueError(std::string("palp convert-tree: expected IN_DIR and OUT_DIR, found ") +
                         (a.in.empty() ? "neither" : "only IN_DIR " + a.in));
    }
    const fs::path inDir = fs::path(a.in).lexically_normal();
    const fs::path outDir = fs::path(a.out).lexically_normal();
    std::int64_t shardIndex = 0, shardCount = 0;
    if (!a.shard.empty()) std::tie(shardIndex, shardCount) = parseShard(a.shard);
    (void)loadOptions(a.flags);  // refuses a bad --crop before any work
    const std::string options = describeConvertFlags(a.flags);
    std::error_code ec;
    if (!fs::is_directory(inDir, ec))
        throw IoError(inDir.string() + ": expected a folder of scans, found " +
                      (fs::exists(inDir, ec) ? "a file" : "nothing"));
    fs::create_directories(outDir, ec);
    if (!fs::is_directory(outDir, ec)) {
        throw IoError(outDir.string() + ": expected an output folder, found " +
                      (fs::exists(outDir) ? "a file" : "none, and it could not be created"));
    }
    if (fs::equivalent(inDir, outDir, ec)) {
        throw ValueError("palp convert-tree: expected an OUT_DIR other than IN_DIR, found " +
                         outDir.string() + " for both (give a folder of its own, inside " +
                         "IN_DIR if you like: it is left out of the search)");
    }

    // Every scan found and named; this run's share by stable index.
    const std::vector<volume::FoundScan> found = volume::findScans(inDir, {outDir});
    const std::vector<PlannedScan> plan = planTree(found, inDir);
    std::vector<std::size_t> mine;
    for (std::size_t k = 0; k < plan.size(); ++k) {
        if (shardCount == 0 || static_cast<std::int64_t>(k) % shardCount == shardIndex)
            mine.push_back(k);
    }
    Manifest manifest;
    manifest.options = options;
    manifest.shard = shardCount == 0
                         ? std::string("all")
                         : std::to_string(shardIndex) + "/" + std::to_string(shardCount);
    manifest.series = mine.size();
    manifest.found = plan.size();
    const fs::path manifestPath = outDir / manifestName(shardIndex, shardCount);

    // With --resume, what an earlier run (of any shard) did and is still valid is kept.
    std::vector<std::size_t> todo;
    std::size_t kept = 0;
    {
        const std::map<RowKey, ManifestRow> before =
            a.resume ? doneBefore(outDir, options) : std::map<RowKey, ManifestRow>{};
        for (const std::size_t k : mine) {
            const auto at = before.find(RowKey{plan[k].output, plan[k].input});
            if (at != before.end() && plan[k].collision.empty() &&
                stillDone(at->second, baseRow(plan[k]), outDir)) {
                insertRow(manifest.rows, at->second);
                ++kept;
            } else {
                todo.push_back(k);
            }
        }
    }

    // SIGINT / SIGTERM (Slurm's scancel) stop the loop between series: the manifest written
    // last lists only complete outputs.
    const InterruptGuard guard;
    writeManifest(manifestPath, manifest);
    std::map<TreeStatus, std::size_t> tally;
    std::size_t step = kept;
    for (const std::size_t k : todo) {
        if (InterruptGuard::interrupted()) break;
        ++step;
        ManifestRow row =
            convertOne(plan[k], outDir, a.flags, progressLabel(step, mine.size(), plan[k].input));
        ++tally[row.status];
        if (row.status == TreeStatus::Refused || row.status == TreeStatus::Failed) {
            endProgress();
            std::fprintf(stderr, "palp convert-tree: %s %s: %s\n", statusName(row.status),
                         plan[k].input.c_str(), row.message.c_str());
        }
        insertRow(manifest.rows, std::move(row));
        writeManifest(manifestPath, manifest);
    }
    endProgress();

    const std::string share =
        shardCount == 0 ? std::string()
                        : ", " + std::to_string(mine.size()) + " in shard " + manifest.shard;
    if (!globals().quiet) {
        std::printf(
            "palp convert-tree: %zu series found%s: %zu converted, %zu kept from an earlier run, "
            "%zu refused, %zu failed, %zu skipped (no images); manifest %s\n",
            plan.size(), share.c_str(), tally[TreeStatus::Done], kept, tally[TreeStatus::Refused],
            tally[TreeStatus::Failed], tally[TreeStatus::Skipped], manifestPath.c_str());
    }
    if (InterruptGuard::interrupted()) {
        std::fprintf(stderr,
                     "palp convert-tree: interrupted: %zu of %zu series listed in %s (each done "
                     "one complete); run again with --resume to convert the rest\n",
                     manifest.rows.size(), mine.size(), manifestPath.c_str());
        return 128 + InterruptGuard::signal();  // as a shell reports a process the signal stopped
    }
    if (tally[TreeStatus::Failed] > 0) return 2;
    return tally[TreeStatus::Refused] > 0 ? 1 : 0;
}

}  // namespace

Command addConvertTree(CLI::App& root) {
    auto args = std::make_shared<TreeArgs>();
    CLI::App* app = root.add_subcommand(
        "convert-tree",
        "Convert every DICOM series, NIfTI, NRRD and MetaImage file under a folder into .vdb "
        "volumes in one process, with a manifest (resumable, shardable for job arrays)");
    app->add_option("IN_DIR", args->in, "Folder of scans (searched recursively)");
    app->add_option("OUT_DIR", args->out,
                    "Output folder (created): the .vdb of each series at a name derived from its "
                    "input, and the manifest");
    addConvertFlags(*app, args->flags);
    app->add_flag("--resume", args->resume,
                  "Keep the series a manifest in OUT_DIR lists as done whose output is complete "
                  "and whose input is unchanged; convert the rest");
    app->add_option("--shard", args->shard,
                    "i/N: convert only the series whose index (in the order of their output "
                    "names) modulo N is i, listed in OUT_DIR/manifest.shard-i-of-N.tsv (e.g. "
                    "$SLURM_ARRAY_TASK_ID/$SLURM_ARRAY_TASK_COUNT)");
    CLI::App* merge = app->add_subcommand(
        "merge", "Merge the shard manifests of OUT_DIR into OUT_DIR/manifest.tsv");
    merge->add_option("OUT_DIR", args->mergeDir, "Output folder of the shards")->required();
    return {app, [args, merge]() -> int {
                if (merge->parsed()) return mergeManifests(args->mergeDir, globals().quiet);
                return runTree(*args);
            }};
}

}  // namespace palp::tool
