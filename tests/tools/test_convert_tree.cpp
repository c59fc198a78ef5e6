// `palp convert-tree` run as a user runs it: a generated archive (DICOM series in folders of
// their own and two in one folder, a NIfTI file, a series with a truncated file, a text file)
// converted in one process gives, series by series, the grid `palp convert` gives for that
// series alone; --resume converts only what is missing; four shards and their merge equal the
// one-process run; SIGINT and SIGKILL mid-run leave a manifest that lists only complete outputs.
#include <fcntl.h>
#include <gtest/gtest.h>
#include <nifti1.h>
#include <signal.h>
#include <spawn.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <map>
#include <regex>
#include <set>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include "palp/volume/dicom.h"
#include "palp/volume/find_scans.h"
#include "palp/volume/load.h"
#include "test_support.h"
#include "tilted_series.h"

extern char** environ;

namespace {

namespace fs = std::filesystem;
using palp::test::runCommand;
using palp::test::TempDir;

std::string quoted(const fs::path& p) { return "'" + p.string() + "'"; }

std::string palpCommand() { return palp::test::palpTool().string(); }

/// The generated CT (tests/support/tilted_series.h) as a DICOM series in @p dir.
void writeSeries(const fs::path& dir, int cols, int rows, int slices, double tiltDeg,
                 const std::string& description) {
    const palp::volume::SliceStack st =
        palp::test::tiltedSeries(cols, rows, slices, 0.8e-3, 1.0e-3, tiltDeg);
    palp::volume::DicomWriteOptions wo;
    wo.seriesDescription = description;
    wo.gantryTiltDeg = tiltDeg;
    palp::volume::writeDicomSeries(st, dir, wo);
}

/// A 24 x 20 x 12 int16 NIfTI-1 file with 1 x 1.2 x 1.5 mm voxels and a shifted sform, of
/// @p nt time points.
void writeNifti(const fs::path& file, int nt = 1) {
    constexpr int nx = 24, ny = 20, nz = 12;
    nifti_1_header h{};
    h.sizeof_hdr = 348;
    h.dim[0] = nt > 1 ? 4 : 3;
    h.dim[1] = nx;
    h.dim[2] = ny;
    h.dim[3] = nz;
    for (int d = 4; d < 8; ++d) h.dim[d] = 1;
    h.dim[4] = static_cast<short>(nt);
    h.datatype = DT_INT16;
    h.bitpix = 16;
    h.pixdim[0] = 1;
    h.pixdim[1] = 1.0f;
    h.pixdim[2] = 1.2f;
    h.pixdim[3] = 1.5f;
    h.vox_offset = 352;
    h.scl_slope = 1;
    h.xyzt_units = NIFTI_UNITS_MM;
    h.sform_code = 1;
    const float srow[3][4] = {{1.0f, 0, 0, -12}, {0, 1.2f, 0, 7}, {0, 0, 1.5f, 30}};
    std::memcpy(h.srow_x, srow[0], sizeof h.srow_x);
    std::memcpy(h.srow_y, srow[1], sizeof h.srow_y);
    std::memcpy(h.srow_z, srow[2], sizeof h.srow_z);
    std::memcpy(h.magic, "n+1", 4);
    std::string bytes(352, '\0');
    std::memcpy(bytes.data(), &h, sizeof h);
    for (int t = 0; t < nt; ++t)
        for (int k = 0; k < nz; ++k)
            for (int j = 0; j < ny; ++j)
                for (int i = 0; i < nx; ++i) {
                    const auto v =
                        static_cast<std::int16_t>((i * 7 + j * 3 + k * 11 + t * 50) % 400 + 5);
                    char two[2];
                    std::memcpy(two, &v, 2);
                    bytes.append(two, 2);
                }
    palp::test::writeFile(file, bytes);
}

/// The test archive: four good DICOM series (two sharing a folder), a NIfTI file, a series
/// whose last file is cut short, and a text file. Returns the truncated file.
fs::path writeArchive(const fs::path& root) {
    writeSeries(root / "study1" / "axial", 40, 36, 14, 0, "axial");
    writeSeries(root / "study1" / "tilted", 36, 32, 12, 12, "tilted");
    // Two series in one folder, their files side by side.
    const fs::path mixed = root / "study2" / "mixed";
    fs::create_directories(mixed);
    for (const char* name : {"a", "b"}) {
        const fs::path tmp = root / (std::string("tmp_") + name);
        writeSeries(tmp, name[0] == 'a' ? 32 : 28, 30, name[0] == 'a' ? 10 : 11, 0,
                    std::string("mixed ") + name);
        for (const auto& e : fs::directory_iterator(tmp))
            fs::rename(e.path(), mixed / (std::string(name) + "_" + e.path().filename().string()));
        fs::remove(tmp);
    }
    fs::create_directories(root / "nifti");
    writeNifti(root / "nifti" / "brain.nii");
    writeSeries(root / "broken", 30, 28, 9, 0, "broken");
    std::vector<fs::path> files;
    for (const auto& e : fs::directory_iterator(root / "broken")) files.push_back(e.path());
    std::sort(files.begin(), files.end());
    fs::resize_file(files.back(), fs::file_size(files.back()) - 500);
    std::ofstream(root / "README.txt") << "not a scan\n";
    return files.back();
}

/// One row of a manifest, its fields as written.
struct Row {
    std::string output, status, input, uid, format, files, sourceBytes, bytes, message;
    bool operator==(const Row&) const = default;
};

std::vector<std::string> split(const std::string& line) {
    std::vector<std::string> f;
    std::stringstream ss(line);
    std::string field;
    while (std::getline(ss, field, '\t')) f.push_back(field);
    if (!line.empty() && line.back() == '\t') f.emplace_back();
    return f;
}

/// The rows of @p manifest (every '#' line and the column line checked and left out).
std::vector<Row> readRows(const fs::path& manifest) {
    std::ifstream in(manifest);
    EXPECT_TRUE(in.good()) << manifest;
    std::vector<Row> rows;
    std::string line;
    bool columns = false;
    std::getline(in, line);
    EXPECT_EQ(line, "# palp convert-tree manifest 1");
    while (std::getline(in, line)) {
        if (line.rfind("# ", 0) == 0) continue;
        if (!columns) {
            EXPECT_EQ(line.rfind("output\tstatus\tinput\tseries_uid", 0), 0u) << line;
            columns = true;
            continue;
        }
        const auto f = split(line);
        EXPECT_EQ(f.size(), 9u) << line;
        if (f.size() != 9) continue;
        rows.push_back({f[0], f[1], f[2], f[3], f[4], f[5], f[6], f[7], f[8]});
    }
    EXPECT_TRUE(columns) << manifest;
    return rows;
}

std::map<std::string, Row> byInputAndUid(const std::vector<Row>& rows) {
    std::map<std::string, Row> m;
    for (const Row& r : rows) m[r.input + " " + r.uid] = r;
    return m;
}

/// Leaves with different origins, masks or values (a's leaves looked up in b, and the counts).
std::size_t leavesDiffering(const palp::volume::Volume& a, const palp::volume::Volume& b) {
    const auto& ta = a.grid->tree();
    const auto& tb = b.grid->tree();
    std::size_t differ = ta.leafCount() > tb.leafCount() ? ta.leafCount() - tb.leafCount()
                                                         : tb.leafCount() - ta.leafCount();
    for (auto it = ta.cbeginLeaf(); it; ++it) {
        const auto* other = tb.probeConstLeaf(it->origin());
        if (!other || other->getValueMask() != it->getValueMask() ||
            std::memcmp(other->buffer().data(), it->buffer().data(), sizeof(float) * it->SIZE) != 0)
            ++differ;
    }
    return differ;
}

/// The grids of two .vdb files are the same: transform, background, active voxels, values.
void expectSameGrid(const fs::path& a, const fs::path& b) {
    SCOPED_TRACE(a.string() + " vs " + b.string());
    const palp::volume::Volume va = palp::volume::loadVdb(a);
    const palp::volume::Volume vb = palp::volume::loadVdb(b);
    EXPECT_GT(va.grid->activeVoxelCount(), 500u);
    EXPECT_EQ(va.grid->activeVoxelCount(), vb.grid->activeVoxelCount());
    EXPECT_TRUE(va.grid->transform() == vb.grid->transform());
    EXPECT_EQ(va.grid->background(), vb.grid->background());
    EXPECT_EQ(leavesDiffering(va, vb), 0u);
    EXPECT_EQ(va.info.seriesUid, vb.info.seriesUid);
    EXPECT_EQ(va.info.modality, vb.info.modality);
    EXPECT_EQ(va.info.originalDims, vb.info.originalDims);
}

/// Every visible .vdb under @p dir, relative, '/'-separated.
std::set<std::string> visibleOutputs(const fs::path& dir) {
    std::set<std::string> out;
    for (const auto& e : fs::recursive_directory_iterator(dir)) {
        const std::string name = e.path().filename().string();
        if (e.is_regular_file() && name.front() != '.' && e.path().extension() == ".vdb")
            out.insert(e.path().lexically_relative(dir).generic_string());
    }
    return out;
}

/// Every file under @p dir whose name starts with '.' (an atomic write's temporary).
std::vector<fs::path> hiddenFiles(const fs::path& dir) {
    std::vector<fs::path> out;
    for (const auto& e : fs::recursive_directory_iterator(dir))
        if (e.path().filename().string().front() == '.') out.push_back(e.path());
    return out;
}

/// "N converted, K kept" of the tool's summary line.
std::pair<int, int> convertedAndKept(const std::string& output) {
    std::smatch m;
    const std::regex re("(\\d+) converted, (\\d+) kept from an earlier run");
    if (!std::regex_search(output, m, re)) {
        ADD_FAILURE() << "no summary in: " << output;
        return {-1, -1};
    }
    return {std::stoi(m[1]), std::stoi(m[2])};
}

TEST(ConvertTree, EverySeriesAsConvertGivesItAloneAndTheBrokenOneRefused) {
    TempDir tmp;
    const fs::path in = tmp / "archive", out = tmp / "out";
    const fs::path truncated = writeArchive(in);
    const auto r = runCommand(palpCommand() + " convert-tree " + quoted(in) + " " + quoted(out));
    EXPECT_EQ(r.exitCode, 1) << r.output;  // one series refused, none failed
    EXPECT_NE(r.output.find("6 series found: 5 converted, 0 kept from an earlier run, 1 refused, "
                            "0 failed, 0 skipped"),
              std::string::npos)
        << r.output;
    const std::vector<Row> rows = readRows(out / "manifest.tsv");
    ASSERT_EQ(rows.size(), 6u);
    std::set<std::string> done;
    for (const Row& row : rows) {
        SCOPED_TRACE(row.input + " " + row.uid);
        if (row.input == "broken") {
            EXPECT_EQ(row.status, "refused");
            EXPECT_NE(row.message.find(truncated.string()), std::string::npos) << row.message;
            EXPECT_NE(row.message.find("truncated"), std::string::npos) << row.message;
            EXPECT_FALSE(fs::exists(out / row.output));
            continue;
        }
        ASSERT_EQ(row.status, "done") << row.message;
        done.insert(row.output);
        EXPECT_EQ(std::to_string(fs::file_size(out / row.output)), row.bytes);
        // The same series through `palp convert` alone.
        const fs::path ref = tmp / "ref.vdb";
        const std::string alone =
            row.format == "DICOM"
                ? palpCommand() + " -q convert " + quoted(in / row.input) + " --series " + row.uid +
                      " -o " + quoted(ref)
                : palpCommand() + " -q convert " + quoted(in / row.input) + " -o " + quoted(ref);
        const auto c = runCommand(alone);
        ASSERT_EQ(c.exitCode, 0) << c.output;
        expectSameGrid(out / row.output, ref);
        if (row.format == "DICOM") {
            EXPECT_EQ(row.output, (row.input == "." ? "" : row.input + "/") + row.uid + ".vdb");
        } else {
            EXPECT_EQ(row.output, "nifti/brain.nii.vdb");
            EXPECT_EQ(row.format, "NIfTI");
        }
    }
    // Both series of the shared folder, each on its own; nothing else written.
    EXPECT_EQ(std::count_if(rows.begin(), rows.end(),
                            [](const Row& x) { return x.input == "study2/mixed"; }),
              2);
    EXPECT_EQ(visibleOutputs(out), done);
    EXPECT_TRUE(hiddenFiles(out).empty());
}

TEST(ConvertTree, ResumeConvertsOnlyWhatIsMissing) {
    TempDir tmp;
    const fs::path in = tmp / "archive", out = tmp / "out";
    writeArchive(in);
    ASSERT_EQ(
        runCommand(palpCommand() + " -q convert-tree " + quoted(in) + " " + quoted(out)).exitCode,
        1);
    std::vector<Row> rows = readRows(out / "manifest.tsv");
    ASSERT_EQ(rows.size(), 6u);
    std::vector<Row> done;
    for (const Row& row : rows)
        if (row.status == "done") done.push_back(row);
    ASSERT_EQ(done.size(), 5u);
    // One output deleted; another's row dropped from the manifest (as if the run had been
    // killed after writing the output and before the manifest).
    fs::remove(out / done[0].output);
    {
        std::ifstream inFile(out / "manifest.tsv");
        std::stringstream kept;
        std::string line;
        while (std::getline(inFile, line))
            if (line.rfind(done[1].output + "\t", 0) != 0) kept << line << '\n';
        inFile.close();
        std::ofstream(out / "manifest.tsv") << kept.str();
    }
    std::map<std::string, fs::file_time_type> before;
    for (const Row& row : done)
        if (fs::exists(out / row.output))
            before[row.output] = fs::last_write_time(out / row.output);
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
    const auto r =
        runCommand(palpCommand() + " convert-tree --resume " + quoted(in) + " " + quoted(out));
    EXPECT_EQ(r.exitCode, 1) << r.output;
    // The two missing ones and the refused one again; the three others kept untouched.
    EXPECT_EQ(convertedAndKept(r.output), std::make_pair(2, 3)) << r.output;
    EXPECT_NE(r.output.find("1 refused"), std::string::npos) << r.output;
    for (const Row& row : done) {
        SCOPED_TRACE(row.output);
        ASSERT_TRUE(fs::exists(out / row.output));
        const bool redone = row.output == done[0].output || row.output == done[1].output;
        EXPECT_EQ(fs::last_write_time(out / row.output) != before[row.output], redone);
    }
    EXPECT_EQ(byInputAndUid(readRows(out / "manifest.tsv")), byInputAndUid(rows));
    // A manifest of other options is not resumed into.
    const auto other = runCommand(palpCommand() + " -q convert-tree --resume --voxel-size 2 " +
                                  quoted(in) + " " + quoted(out));
    EXPECT_EQ(other.exitCode, 1);
    EXPECT_NE(other.output.find("manifest.tsv: expected a manifest of options 'voxel-size=2 "),
              std::string::npos)
        << other.output;
}

TEST(ConvertTree, FourShardsAndTheirMergeEqualTheOneProcessRun) {
    TempDir tmp;
    const fs::path in = tmp / "archive", one = tmp / "one", sharded = tmp / "sharded";
    writeArchive(in);
    ASSERT_EQ(
        runCommand(palpCommand() + " -q convert-tree " + quoted(in) + " " + quoted(one)).exitCode,
        1);
    std::size_t listed = 0;
    for (int i = 0; i < 4; ++i) {
        const auto r = runCommand(palpCommand() + " convert-tree --shard " + std::to_string(i) +
                                  "/4 " + quoted(in) + " " + quoted(sharded));
        EXPECT_TRUE(r.exitCode == 0 || r.exitCode == 1) << r.output;
        EXPECT_NE(r.output.find("6 series found, "), std::string::npos) << r.output;
        const auto rows = readRows(sharded / ("manifest.shard-" + std::to_string(i) + "-of-4.tsv"));
        EXPECT_EQ(rows.size(), i < 2 ? 2u : 1u);  // 6 series: indices 0,4 | 1,5 | 2 | 3
        listed += rows.size();
        // Before the merge, a missing shard is named.
        if (i == 2) {
            const auto early = runCommand(palpCommand() + " convert-tree merge " + quoted(sharded));
            EXPECT_EQ(early.exitCode, 1) << early.output;
            EXPECT_NE(early.output.find("shard 3/4: no manifest"), std::string::npos)
                << early.output;
        }
    }
    EXPECT_EQ(listed, 6u);
    const auto merge = runCommand(palpCommand() + " convert-tree merge " + quoted(sharded));
    EXPECT_EQ(merge.exitCode, 1) << merge.output;  // the broken series stays refused
    EXPECT_NE(merge.output.find("6 of 6 series listed: 5 done, 1 refused"), std::string::npos)
        << merge.output;
    const std::vector<Row> oneRows = readRows(one / "manifest.tsv");
    const std::vector<Row> mergedRows = readRows(sharded / "manifest.tsv");
    EXPECT_EQ(mergedRows, oneRows);  // row for row, sizes and messages included
    EXPECT_EQ(visibleOutputs(sharded), visibleOutputs(one));
    for (const std::string& o : visibleOutputs(one)) expectSameGrid(sharded / o, one / o);
}

/// Runs palp with @p args in the background, its output to @p log.
pid_t spawnPalp(const std::vector<std::string>& args, const fs::path& log) {
    std::vector<std::string> all{palpCommand()};
    all.insert(all.end(), args.begin(), args.end());
    std::vector<char*> argv;
    for (std::string& a : all) argv.push_back(a.data());
    argv.push_back(nullptr);
    posix_spawn_file_actions_t fa;
    posix_spawn_file_actions_init(&fa);
    posix_spawn_file_actions_addopen(&fa, 1, log.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
    posix_spawn_file_actions_adddup2(&fa, 1, 2);
    pid_t pid = -1;
    const int rc = posix_spawn(&pid, argv[0], &fa, nullptr, argv.data(), environ);
    posix_spawn_file_actions_destroy(&fa);
    EXPECT_EQ(rc, 0);
    return rc == 0 ? pid : -1;
}

/// The exit status as a shell reports it (128 + the signal when one ended the process).
int waitFor(pid_t pid) {
    int status = 0;
    if (waitpid(pid, &status, 0) != pid) return -1;
    if (WIFEXITED(status)) return WEXITSTATUS(status);
    return WIFSIGNALED(status) ? 128 + WTERMSIG(status) : -1;
}

/// Waits (up to 60 s) until @p manifest lists at least @p n rows; false if it never does.
bool waitForRows(const fs::path& manifest, std::size_t n) {
    const auto end = std::chrono::steady_clock::now() + std::chrono::seconds(60);
    while (std::chrono::steady_clock::now() < end) {
        if (fs::exists(manifest)) {
            std::ifstream in(manifest);
            std::size_t rows = 0;
            std::string line;
            while (std::getline(in, line))
                if (line.rfind("# ", 0) != 0 && line.rfind("output\t", 0) != 0) ++rows;
            if (rows >= n) return true;
        }
        std::this_thread::sleep_for(std::chrono::milliseconds(2));
    }
    return false;
}

constexpr int kSignalSeries = 10;

/// Ten series of 64 x 56 x 48, converted at 0.25 mm so that each takes a while.
void writeSignalArchive(const fs::path& root) {
    for (int i = 0; i < kSignalSeries; ++i) {
        // Built by appending: GCC 12 reports a false -Wstringop-overflow for "s" + std::string.
        std::string name(1, 's');
        name += std::to_string(i);
        writeSeries(root / name, 64, 56, 48, 0, name);
    }
}

/// Interrupts a run with @p sig once a first series is listed; checks that what the manifest
/// lists as done is complete, then that --resume converts only the rest.
void interruptAndResume(int sig) {
    TempDir tmp;
    const fs::path in = tmp / "archive", out = tmp / "out";
    writeSignalArchive(in);
    const std::vector<std::string> args{"-q",   "convert-tree", "--voxel-size",
                                        "0.25", in.string(),    out.string()};
    const pid_t pid = spawnPalp(args, tmp / "run.log");
    ASSERT_GT(pid, 0);
    const bool listed = waitForRows(out / "manifest.tsv", 1);
    kill(pid, sig);
    const int status = waitFor(pid);
    ASSERT_TRUE(listed);
    std::ifstream logFile(tmp / "run.log");
    const std::string log((std::istreambuf_iterator<char>(logFile)), {});
    EXPECT_EQ(status, 128 + sig) << log;
    if (sig == SIGINT) {
        EXPECT_NE(log.find("interrupted: "), std::string::npos) << log;
    }
    const std::vector<Row> rows = readRows(out / "manifest.tsv");
    ASSERT_GE(rows.size(), 1u);
    ASSERT_LT(rows.size(), static_cast<std::size_t>(kSignalSeries)) << "the run was not stopped";
    std::set<std::string> listedOutputs;
    for (const Row& row : rows) {
        SCOPED_TRACE(row.output);
        EXPECT_EQ(row.status, "done");
        EXPECT_EQ(std::to_string(fs::file_size(out / row.output)), row.bytes);
        EXPECT_GT(palp::volume::loadVdb(out / row.output).grid->activeVoxelCount(), 1000u);
        listedOutputs.insert(row.output);
    }
    if (sig == SIGINT) {
        // It stopped after the series in hand: every output is listed, no temporary is left.
        EXPECT_EQ(visibleOutputs(out), listedOutputs);
        EXPECT_TRUE(hiddenFiles(out).empty());
    }
    std::map<std::string, fs::file_time_type> before;
    for (const std::string& o : listedOutputs) before[o] = fs::last_write_time(out / o);
    std::vector<std::string> resume = args;
    resume.erase(resume.begin());  // not quiet: the summary says what was done
    resume.insert(resume.begin() + 1, "--resume");
    const pid_t again = spawnPalp(resume, tmp / "resume.log");
    ASSERT_EQ(waitFor(again), 0);
    std::ifstream resumeLog(tmp / "resume.log");
    const std::string summary((std::istreambuf_iterator<char>(resumeLog)), {});
    EXPECT_EQ(convertedAndKept(summary),
              std::make_pair(kSignalSeries - static_cast<int>(rows.size()),
                             static_cast<int>(rows.size())))
        << summary;
    for (const auto& [o, t] : before) EXPECT_EQ(fs::last_write_time(out / o), t) << o;
    const std::vector<Row> all = readRows(out / "manifest.tsv");
    EXPECT_EQ(all.size(), static_cast<std::size_t>(kSignalSeries));
    for (const Row& row : all) EXPECT_EQ(row.status, "done") << row.output;
}

TEST(ConvertTree, SigintStopsAfterTheSeriesInHandAndResumeConvertsTheRest) {
    interruptAndResume(SIGINT);
}

TEST(ConvertTree, SigkillLeavesOnlyCompleteOutputsListedAndResumeConvertsTheRest) {
    interruptAndResume(SIGKILL);
}

/// A DICOM file cut inside its header, before its SeriesInstanceUID: its series cannot be told.
fs::path cutBeforeTheSeriesUid(const fs::path& from, const fs::path& to) {
    fs::create_directories(to.parent_path());
    fs::copy_file(from, to);
    fs::resize_file(to, 300);  // the preamble, "DICM" and part of the file meta information
    return to;
}

TEST(ConvertTree, AFileWhoseSeriesCannotBeToldRefusesTheSeriesBesideIt) {
    // As `palp convert FOLDER` refuses a folder with such a file, the tree refuses the series
    // in its folder (naming the file) and converts the others; alone in a folder, the file is a
    // scan of its own, refused with the reason.
    TempDir tmp;
    const fs::path in = tmp / "archive", out = tmp / "out";
    writeSeries(in / "good", 30, 28, 8, 0, "good");
    writeSeries(in / "tainted", 30, 28, 8, 0, "tainted");
    const fs::path first = *fs::directory_iterator(in / "good");
    const fs::path beside = cutBeforeTheSeriesUid(first, in / "tainted" / "cut.dcm");
    const fs::path alone = cutBeforeTheSeriesUid(first, in / "lonely" / "cut.dcm");
    const auto found = palp::volume::findScans(in);
    ASSERT_EQ(found.size(), 3u);
    EXPECT_EQ(found[0].folder, in / "good");
    EXPECT_EQ(found[0].files.size(), 8u);
    EXPECT_EQ(found[1].folder, in / "lonely");
    EXPECT_TRUE(found[1].unreadable);
    EXPECT_EQ(found[1].files, std::vector<fs::path>{alone});
    EXPECT_EQ(found[2].folder, in / "tainted");
    EXPECT_EQ(found[2].files.size(), 9u);
    EXPECT_NE(std::find(found[2].files.begin(), found[2].files.end(), beside),
              found[2].files.end());
    // The same refusal as `palp convert` of the folder.
    const auto alonePalp = runCommand(palpCommand() + " -q convert " + quoted(in / "tainted") +
                                      " -o " + quoted(tmp / "x.vdb"));
    EXPECT_EQ(alonePalp.exitCode, 1);
    const auto r = runCommand(palpCommand() + " -q convert-tree " + quoted(in) + " " + quoted(out));
    EXPECT_EQ(r.exitCode, 1) << r.output;
    const auto rows = readRows(out / "manifest.tsv");
    ASSERT_EQ(rows.size(), 3u);
    EXPECT_EQ(rows[0].status, "done");
    EXPECT_EQ(rows[1].output, "lonely/unreadable-dicom.vdb");
    EXPECT_EQ(rows[1].status, "refused");
    EXPECT_NE(rows[1].message.find(alone.string() + ": expected a complete DICOM header"),
              std::string::npos)
        << rows[1].message;
    EXPECT_EQ(rows[2].input, "tainted");
    EXPECT_EQ(rows[2].status, "refused");
    EXPECT_NE(rows[2].message.find(beside.string()), std::string::npos) << rows[2].message;
    EXPECT_NE(alonePalp.output.find(rows[2].message), std::string::npos)
        << alonePalp.output << " vs " << rows[2].message;
}

TEST(ConvertTree, VolumeFlagReachesEveryScan) {
    // A 4D NIfTI without --volume is refused with the flag to give; with --volume 1 it
    // converts to what `palp convert --volume 1` gives.
    TempDir tmp;
    const fs::path in = tmp / "archive";
    fs::create_directories(in);
    writeNifti(in / "fmri.nii", 3);
    auto r = runCommand(palpCommand() + " -q convert-tree " + quoted(in) + " " + quoted(tmp / "a"));
    EXPECT_EQ(r.exitCode, 1) << r.output;
    auto rows = readRows(tmp / "a" / "manifest.tsv");
    ASSERT_EQ(rows.size(), 1u);
    EXPECT_EQ(rows[0].status, "refused");
    EXPECT_NE(rows[0].message.find("3 time points"), std::string::npos) << rows[0].message;
    EXPECT_NE(rows[0].message.find("\\n(choose the time point with --volume N)"),
              std::string::npos)
        << rows[0].message;  // the message's newline, escaped in the manifest
    r = runCommand(palpCommand() + " -q convert-tree --volume 1 " + quoted(in) + " " +
                   quoted(tmp / "b"));
    EXPECT_EQ(r.exitCode, 0) << r.output;
    rows = readRows(tmp / "b" / "manifest.tsv");
    ASSERT_EQ(rows.size(), 1u);
    EXPECT_EQ(rows[0].status, "done");
    ASSERT_EQ(runCommand(palpCommand() + " -q convert --volume 1 " + quoted(in / "fmri.nii") +
                         " -o " + quoted(tmp / "ref.vdb"))
                  .exitCode,
              0);
    expectSameGrid(tmp / "b" / "fmri.nii.vdb", tmp / "ref.vdb");
}

TEST(ConvertTree, NativeVoxelSizeKeepsTheSeriesOwnSpacing) {
    // --voxel-size native on a 0.5 x 0.5 x 1 mm series: one voxel per pixel above the CT
    // threshold (not twice the voxels at 0.5 mm), recorded in the manifest's options and shown by
    // `palp info`; a tilted series is refused by `palp convert` and listed as refused by
    // convert-tree; a voxel size that is neither a length nor "native" is refused.
    TempDir tmp;
    const fs::path in = tmp / "archive";
    const palp::volume::SliceStack st = palp::test::tiltedSeries(20, 16, 9, 0.5e-3, 1e-3, 0);
    palp::volume::writeDicomSeries(st, in / "even");
    std::uint64_t above = 0;
    for (const auto& sl : st.slices)
        for (const float v : sl.values) above += v >= -900.0f ? 1 : 0;
    auto r = runCommand(palpCommand() + " convert " + quoted(in / "even") +
                        " --voxel-size native -o " + quoted(tmp / "n.vdb"));
    ASSERT_EQ(r.exitCode, 0) << r.output;
    EXPECT_NE(r.output.find("voxel 0.5 x 0.5 x 1 mm, " + std::to_string(above) + " active voxels"),
              std::string::npos)
        << r.output;
    r = runCommand(palpCommand() + " info --json " + quoted(tmp / "n.vdb"));
    ASSERT_EQ(r.exitCode, 0) << r.output;
    EXPECT_NE(r.output.find("\"voxel_sizes_mm\": [\n    0.5,\n    0.5,\n    1.0\n  ]"),
              std::string::npos)
        << r.output;
    writeSeries(in / "tilted", 20, 16, 9, 12.0, "tilted");
    r = runCommand(palpCommand() + " convert " + quoted(in / "tilted") +
                   " --voxel-size native -o " + quoted(tmp / "t.vdb"));
    EXPECT_EQ(r.exitCode, 1) << r.output;
    // A tilted gantry tilts the slices' rows off the patient axes.
    EXPECT_NE(r.output.find("expected rows, columns and slice normal along the patient axes"),
              std::string::npos)
        << r.output;
    r = runCommand(palpCommand() + " -q convert-tree --voxel-size native " + quoted(in) + " " +
                   quoted(tmp / "out"));
    EXPECT_EQ(r.exitCode, 1) << r.output;
    const std::vector<Row> rows = readRows(tmp / "out" / "manifest.tsv");
    ASSERT_EQ(rows.size(), 2u);
    for (const Row& row : rows) {
        if (row.input == "tilted") {
            EXPECT_EQ(row.status, "refused");
            EXPECT_NE(row.message.find("along the patient axes"), std::string::npos) << row.message;
        } else {
            ASSERT_EQ(row.status, "done") << row.message;
            expectSameGrid(tmp / "out" / row.output, tmp / "n.vdb");
        }
    }
    std::ifstream manifest(tmp / "out" / "manifest.tsv");
    const std::string text((std::istreambuf_iterator<char>(manifest)),
                           std::istreambuf_iterator<char>());
    EXPECT_NE(text.find("voxel-size=native"), std::string::npos) << text;
    r = runCommand(palpCommand() + " convert " + quoted(in / "even") + " --voxel-size big -o " +
                   quoted(tmp / "b.vdb"));
    EXPECT_NE(r.exitCode, 0);
    EXPECT_NE(r.output.find("mm or native, found 'big'"), std::string::npos) << r.output;
}

TEST(ConvertTree, OnlyADicomInputLoadsGdcm) {
    // GDCM builds its dictionaries when it is loaded; palp_volume opens its DICOM library (and so
    // GDCM) at the first DICOM only: `palp --version` and a NIfTI conversion never load it.
    TempDir tmp;
    writeNifti(tmp / "brain.nii");
    writeSeries(tmp / "ct", 12, 10, 4, 0.0, "ct");
    const auto loaded = [&](const std::string& args) {
        const auto r = runCommand("LD_DEBUG=files " + palpCommand() + " " + args);
        EXPECT_EQ(r.exitCode, 0) << args << "\n" << r.output;
        return std::make_pair(r.output.find("libgdcmMSFF") != std::string::npos,
                              r.output.find("libpalp_volume_dicom.so") != std::string::npos);
    };
    EXPECT_EQ(loaded("--version"), std::make_pair(false, false));
    EXPECT_EQ(loaded("-q convert " + quoted(tmp / "brain.nii") + " -o " + quoted(tmp / "n.vdb")),
              std::make_pair(false, false));
    EXPECT_EQ(loaded("info " + quoted(tmp / "n.vdb")), std::make_pair(false, false));
    EXPECT_EQ(loaded("-q convert " + quoted(tmp / "ct") + " -o " + quoted(tmp / "c.vdb")),
              std::make_pair(true, true));
}

TEST(ConvertTree, RefusesAnOutputFolderThatIsTheInputAndAMissingInput) {
    TempDir tmp;
    fs::create_directories(tmp / "a");
    auto r =
        runCommand(palpCommand() + " convert-tree " + quoted(tmp / "a") + " " + quoted(tmp / "a"));
    EXPECT_EQ(r.exitCode, 1);
    EXPECT_NE(r.output.find("expected an OUT_DIR other than IN_DIR"), std::string::npos)
        << r.output;
    r = runCommand(palpCommand() + " convert-tree " + quoted(tmp / "nope") + " " +
                   quoted(tmp / "out"));
    EXPECT_EQ(r.exitCode, 1);
    EXPECT_NE(r.output.find("nope: expected a folder of scans, found nothing"), std::string::npos)
        << r.output;
    r = runCommand(palpCommand() + " convert-tree --shard 4/4 " + quoted(tmp / "a") + " " +
                   quoted(tmp / "out"));
    EXPECT_EQ(r.exitCode, 1);
    EXPECT_NE(r.output.find("--shard: expected i/n"), std::string::npos) << r.output;
}

}  // namespace
