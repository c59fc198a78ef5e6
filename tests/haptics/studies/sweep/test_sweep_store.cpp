// A sweep's shards, resume and merge (palp/studies/sweep_store.h): the merged table's bytes do
// not depend on how the samples were split; corrupt or foreign shards and another sweep's
// manifest are refused naming the file and field, and nothing is merged.
#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <sstream>

#include "palp/base/error.h"
#include "palp/studies/sweep_run.h"
#include "palp/studies/sweep_store.h"
#include "sweep_fixture.h"
#include "test_support.h"

namespace {

namespace fs = std::filesystem;
using namespace palp::haptics;
using palp::test::expectThrowWith;
using palp::test::TempDir;

SweepSpec spec(std::uint64_t seed = 3) {
    SweepSpec s;
    s.ranges = parseSweepRanges(palp::test::smallRanges(), "small.json");
    s.samples = 14;  // 5 groups of 3, the last one short
    s.seed = seed;
    return s;
}

std::string slurp(const fs::path& p) {
    std::ifstream in(p, std::ios::binary);
    std::ostringstream s;
    s << in.rdbuf();
    return s.str();
}

/// Runs @p ranges (in the order given, each with a fresh runner: another process) into @p dir
/// and merges; returns the table's bytes.
std::string sweepInParts(const fs::path& dir, const SweepSpec& s,
                         const std::vector<SampleRange>& ranges, std::int64_t chunk = 1000) {
    prepareSweepDir(dir, s);
    for (const auto& r : ranges) {
        SweepRunner runner(s);
        runRange(dir, runner, r, chunk, "test");
    }
    mergeSweep(dir, dir / "table.csv");
    return slurp(dir / "table.csv");
}

class SweepStore : public ::testing::Test {
  protected:
    static void SetUpTestSuite() {
        sOne = new TempDir;
        sTable = sweepInParts(sOne->path(), spec(), {{0, 14}});
    }
    static void TearDownTestSuite() { delete sOne; }
    static TempDir* sOne;
    static std::string sTable;
};
TempDir* SweepStore::sOne = nullptr;
std::string SweepStore::sTable;

TEST_F(SweepStore, OneProcessTableIsSane) {
    std::istringstream in(sTable);
    std::string line;
    std::getline(in, line);
    EXPECT_EQ(line.rfind("sample,strain,frequency,contact,", 0), 0u);
    int rows = 0;
    while (std::getline(in, line)) {
        ++rows;
        // err_rms is finite and small but not zero: the regions differ from the whole mesh.
        std::vector<std::string> cells;
        std::stringstream ls(line);
        std::string c;
        while (std::getline(ls, c, ',')) cells.push_back(c);
        ASSERT_EQ(cells.size(), sweepColumns().size());
        const double force = std::stod(cells[14]), rms = std::stod(cells[16]);
        EXPECT_GT(force, 1e-4) << line;
        EXPECT_GT(rms, 0.0) << line;
        EXPECT_LT(rms, 1.0) << line;
    }
    EXPECT_EQ(rows, 14);
    const std::string side = slurp(sOne->path() / "table.json");
    for (const char* key : {"\"palp_version\"", "\"seed\": 3", "\"columns\"", "\"machine\"",
                            "\"unit\": \"Pa\"", "\"parameters\"", "\"sweep\""})
        EXPECT_NE(side.find(key), std::string::npos) << key;
    EXPECT_TRUE(fs::exists(sOne->path() / "table.timings.csv"));
}

TEST_F(SweepStore, TableBytesDoNotDependOnTheSplit) {
    const SweepSpec s = spec();
    for (std::int64_t n : {2, 3}) {
        TempDir d;
        std::vector<SampleRange> parts;
        for (std::int64_t i = 0; i < n; ++i) parts.push_back(shardRange(s, i, n));
        EXPECT_EQ(sweepInParts(d.path(), s, parts), sTable) << n << " shards";
    }
    // Any split, run backwards, groups cut in two (the reference recomputed), chunked files.
    TempDir d;
    EXPECT_EQ(sweepInParts(d.path(), s, {{10, 14}, {4, 10}, {1, 4}, {0, 1}}, 2), sTable);
}

TEST_F(SweepStore, ResumeComputesOnlyWhatIsMissing) {
    const SweepSpec s = spec();
    TempDir d;
    prepareSweepDir(d.path(), s);
    SweepRunner runner(s);
    runRange(d.path(), runner, {0, 14}, 6, "test");  // shards [0,6) [6,12) [12,14)
    fs::remove(d.path() / "shards" / "shard-0000000006-0000000012.csv");
    // A corrupt shard counts as missing for --resume (and is named).
    {
        std::string text = slurp(d.path() / "shards" / "shard-0000000012-0000000014.csv");
        text.resize(text.size() - 20);
        palp::test::writeFile(d.path() / "shards" / "shard-0000000012-0000000014.csv", text);
    }
    std::vector<std::string> warnings;
    const auto have =
        listShards(d.path(), s, false, [&](const std::string& w) { warnings.push_back(w); });
    ASSERT_EQ(have.size(), 1u);
    ASSERT_EQ(warnings.size(), 1u);
    EXPECT_NE(warnings[0].find("shard-0000000012-0000000014.csv"), std::string::npos);
    EXPECT_TRUE(fs::exists(d.path() / "shards" / "shard-0000000012-0000000014.csv.corrupt"));
    const auto missing = missingRanges({0, 14}, have);
    ASSERT_EQ(missing.size(), 1u);
    EXPECT_EQ(missing[0], (SampleRange{6, 14}));
    EXPECT_EQ(missingRanges({0, 3}, have).size(), 0u);
    SweepRunner again(s);
    runRange(d.path(), again, missing[0], 1000, "test");
    mergeSweep(d.path(), d.path() / "table.csv");
    EXPECT_EQ(slurp(d.path() / "table.csv"), sTable);
}

TEST_F(SweepStore, RefusesCorruptAndForeignShardsAndOtherManifests) {
    const SweepSpec s = spec();
    auto copyOne = [&](const fs::path& to) {
        fs::create_directories(to);
        fs::copy(sOne->path(), to, fs::copy_options::recursive);
        fs::remove(to / "table.csv");
    };
    const std::string shard = "shard-0000000000-0000000014.csv";
    {  // a flipped digit
        TempDir d;
        copyOne(d.path());
        std::string text = slurp(d.path() / "shards" / shard);
        const auto at = text.find("\n3,") + 5;
        text[at] = text[at] == '1' ? '2' : '1';
        palp::test::writeFile(d.path() / "shards" / shard, text);
        expectThrowWith<palp::FormatError>([&] { mergeSweep(d.path(), d.path() / "t.csv"); },
                                           {shard, "fnv1a64", "corrupt"});
        EXPECT_FALSE(fs::exists(d.path() / "t.csv"));
        EXPECT_FALSE(fs::exists(d.path() / "t.json"));
    }
    {  // truncated
        TempDir d;
        copyOne(d.path());
        std::string text = slurp(d.path() / "shards" / shard);
        palp::test::writeFile(d.path() / "shards" / shard, text.substr(0, text.size() / 2));
        expectThrowWith<palp::FormatError>([&] { mergeSweep(d.path(), d.path() / "t.csv"); },
                                           {shard});
        EXPECT_FALSE(fs::exists(d.path() / "t.csv"));
    }
    {  // a shard of another sweep (another seed) dropped in
        TempDir other;
        prepareSweepDir(other.path(), spec(4));
        SweepRunner foreign(spec(4));
        runRange(other.path(), foreign, {0, 3}, 1000, "test");
        TempDir d;
        copyOne(d.path());
        fs::remove(d.path() / "shards" / shard);
        fs::copy(other.path() / "shards" / "shard-0000000000-0000000003.csv",
                 d.path() / "shards" / "shard-0000000000-0000000003.csv");
        expectThrowWith<palp::ValueError>(
            [&] { mergeSweep(d.path(), d.path() / "t.csv"); },
            {"shard-0000000000-0000000003.csv", "'sweep'", s.id(), "another sweep"});
        EXPECT_FALSE(fs::exists(d.path() / "t.csv"));
        // --resume refuses it too rather than computing beside it.
        expectThrowWith<palp::ValueError>([&] { listShards(d.path(), s, false); },
                                          {"shard-0000000000-0000000003.csv", "'sweep'"});
    }
    {  // a manifest of another sweep
        TempDir d;
        copyOne(d.path());
        expectThrowWith<palp::ValueError>([&] { prepareSweepDir(d.path(), spec(9)); },
                                          {"manifest.json", "'sweep'", "seed 3 vs 9"});
        // An edited manifest (seed changed by hand) no longer matches its id.
        std::string m = slurp(d.path() / "manifest.json");
        m.replace(m.find("\"seed\": 3"), 9, "\"seed\": 8");
        palp::test::writeFile(d.path() / "manifest.json", m);
        expectThrowWith<palp::FormatError>([&] { mergeSweep(d.path(), d.path() / "t.csv"); },
                                           {"manifest.json", "'sweep'", "edited"});
        EXPECT_FALSE(fs::exists(d.path() / "t.csv"));
    }
    {  // a gap and an overlap
        TempDir d;
        prepareSweepDir(d.path(), s);
        SweepRunner runner(s);
        runRange(d.path(), runner, {0, 3}, 1000, "test");
        runRange(d.path(), runner, {6, 14}, 1000, "test");
        expectThrowWith<palp::ValueError>([&] { mergeSweep(d.path(), d.path() / "t.csv"); },
                                          {"samples 3..5", "in no shard", "--resume"});
        runRange(d.path(), runner, {2, 6}, 1000, "test");
        expectThrowWith<palp::ValueError>([&] { mergeSweep(d.path(), d.path() / "t.csv"); },
                                          {"shard-0000000002-0000000006.csv", "overlapping"});
        EXPECT_FALSE(fs::exists(d.path() / "t.csv"));
    }
}

}  // namespace
