// CSV traces: one row per snapshot with the documented columns; atomic writes.
#include <gtest/gtest.h>

#include <algorithm>
#include <filesystem>
#include <fstream>
#include <string>
#include <vector>

#include "palp/base/error.h"
#include "palp/studies/trace_csv.h"

namespace palp::haptics {
namespace {

namespace fs = std::filesystem;

fs::path tempDir(const std::string& name) {
    fs::path d = fs::temp_directory_path() / ("palp_test_trace_csv_" + name);
    fs::remove_all(d);
    fs::create_directories(d);
    return d;
}

TEST(TraceCsv, OneRowPerSnapshotWithTheDocumentedColumns) {
    const fs::path dir = tempDir("csv");
    std::vector<Snapshot> snaps(3);
    for (int i = 0; i < 3; ++i) {
        snaps[static_cast<std::size_t>(i)].tick = static_cast<std::uint64_t>(i);
        snaps[static_cast<std::size_t>(i)].timeSeconds = i * 1e-3;
        snaps[static_cast<std::size_t>(i)].stiffness = 300 + i;
        snaps[static_cast<std::size_t>(i)].force = Eigen::Vector3d(0, -0.5 * i, 0);
        snaps[static_cast<std::size_t>(i)].sticking = i == 2;
    }
    writeTraceCsv(dir / "t.csv", snaps);
    std::ifstream in(dir / "t.csv");
    std::string header, line;
    std::getline(in, header);
    EXPECT_EQ(std::count(header.begin(), header.end(), ','), 28);
    EXPECT_EQ(header.rfind("t,tick,probe_x", 0), 0u);
    std::vector<std::string> rows;
    while (std::getline(in, line)) rows.push_back(line);
    ASSERT_EQ(rows.size(), 3u);
    EXPECT_EQ(std::count(rows[2].begin(), rows[2].end(), ','), 28);
    EXPECT_NE(rows[2].find(",302,"), std::string::npos) << rows[2];
    EXPECT_NE(rows[2].find(",-1,"), std::string::npos) << rows[2];
    EXPECT_EQ(rows[2].substr(rows[2].size() - 8), ",1,0,0,0") << rows[2];
    EXPECT_THROW(writeTraceCsv(dir / "missing" / "t.csv", snaps), IoError);
    fs::remove_all(dir);
}

}  // namespace
}  // namespace palp::haptics
