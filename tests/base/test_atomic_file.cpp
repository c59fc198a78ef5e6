#include <gtest/gtest.h>

#include <fstream>
#include <iterator>
#include <stdexcept>
#include <string>

#include "palp/base/atomic_file.h"
#include "palp/base/error.h"

namespace palp {
namespace {

namespace fs = std::filesystem;

std::string contents(const fs::path& p) {
    std::ifstream in(p, std::ios::binary);
    return {std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
}

class AtomicFileTest : public ::testing::Test {
  protected:
    void SetUp() override {
        mDir = fs::temp_directory_path() /
               ("palp_atomic_" + std::to_string(::testing::UnitTest::GetInstance()->random_seed()) +
                "_" + ::testing::UnitTest::GetInstance()->current_test_info()->name());
        fs::remove_all(mDir);
        fs::create_directories(mDir);
    }
    void TearDown() override { fs::remove_all(mDir); }
    std::size_t entries() const {
        return static_cast<std::size_t>(std::distance(fs::directory_iterator(mDir), {}));
    }
    fs::path mDir;
};

TEST_F(AtomicFileTest, WritesReplacesAndLeavesNoTemporary) {
    const fs::path p = mDir / "out.txt";
    writeFileAtomically(p, "text", "first", 5);
    EXPECT_EQ(contents(p), "first");
    writeFileAtomically(p, "text", "second", 6);
    EXPECT_EQ(contents(p), "second");
    EXPECT_EQ(entries(), 1u);
}

TEST_F(AtomicFileTest, AFailureBeforeCommitKeepsTheOldFileAndRemovesTheTemporary) {
    const fs::path p = mDir / "out.txt";
    writeFileAtomically(p, "text", "old", 3);
    try {
        AtomicFile f(p, "text");
        std::ofstream(f.tempPath()) << "half-written";
        EXPECT_TRUE(fs::exists(f.tempPath()));
        EXPECT_EQ(f.tempPath().parent_path(), mDir);
        throw std::runtime_error("writer failed");
    } catch (const std::runtime_error&) {
    }
    EXPECT_EQ(contents(p), "old");
    EXPECT_EQ(entries(), 1u);
}

TEST_F(AtomicFileTest, AMissingDirectoryIsNamed) {
    const fs::path p = mDir / "no" / "such" / "out.txt";
    try {
        writeFileAtomically(p, "trace", "x", 1);
        FAIL() << "no error";
    } catch (const IoError& e) {
        const std::string m = e.what();
        EXPECT_NE(m.find(p.string()), std::string::npos) << m;
        EXPECT_NE(m.find("expected an existing directory"), std::string::npos) << m;
        EXPECT_NE(m.find("for the trace"), std::string::npos) << m;
    }
    EXPECT_FALSE(fs::exists(mDir / "no"));
}

TEST_F(AtomicFileTest, ARenameOntoADirectoryFailsCleanly) {
    const fs::path p = mDir / "taken";
    fs::create_directories(p / "inside");  // rename(file, non-empty dir) fails
    EXPECT_THROW(writeFileAtomically(p, "map", "x", 1), IoError);
    EXPECT_EQ(entries(), 1u);  // the directory only; no temporary left
}

}  // namespace
}  // namespace palp
