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

TEST_F(AtomicFileTest, ADirectoryAsTheTargetIsNamedAsSuchAndNothingIsWritten) {
    // `palp convert x -o DIR` said "could not rename ...: Success" (or "Not a directory" for
    // DIR/, "Device or resource busy" for .): the real reason is that the target is a directory.
    fs::create_directories(mDir / "empty");
    fs::create_directories(mDir / "full" / "inside");
    const fs::path cwd = fs::current_path();
    fs::current_path(mDir);
    for (const fs::path& p : {mDir / "empty", mDir / "full", fs::path(mDir.string() + "/empty/"),
                              mDir / ".", mDir / "..", fs::path("."), fs::path("empty/")}) {
        try {
            writeFileAtomically(p, "volume", "x", 1);
            ADD_FAILURE() << p << ": no error";
        } catch (const IoError& e) {
            const std::string m = e.what();
            EXPECT_EQ(m, p.string() + ": expected a file name for the volume, found a directory")
                << m;
        }
    }
    fs::current_path(cwd);
    EXPECT_EQ(entries(), 2u);  // the two directories; no temporary anywhere
    EXPECT_TRUE(fs::is_empty(mDir / "empty"));
    EXPECT_EQ(std::distance(fs::directory_iterator(mDir / "full"), {}), 1);
    try {
        AtomicFile f("", "trace");
        ADD_FAILURE() << "no error";
    } catch (const IoError& e) {
        EXPECT_EQ(std::string(e.what()),
                  "'': expected a file name for the trace, found an empty path");
    }
}

TEST_F(AtomicFileTest, ATargetThatBecomesADirectoryBeforeCommitIsNamedAndTheTemporaryGoes) {
    const fs::path p = mDir / "late";
    try {
        AtomicFile f(p, "trace");
        std::ofstream(f.tempPath()) << "content";
        fs::create_directories(p);  // another process takes the name meanwhile
        f.commit();
        ADD_FAILURE() << "no error";
    } catch (const IoError& e) {
        EXPECT_EQ(std::string(e.what()), p.string() +
                                             ": expected a file name for the trace, found a "
                                             "directory (the trace was not written)");
    }
    EXPECT_EQ(entries(), 1u);  // the directory only
}

TEST_F(AtomicFileTest, ARenameFailureGivesRenamesOwnReason) {
    // The temporary vanishes before commit: rename() fails with ENOENT, and its reason is what
    // the message says (never "Success").
    const fs::path p = mDir / "sub" / "out.txt";
    fs::create_directories(p.parent_path());
    try {
        AtomicFile f(p, "map");
        std::ofstream(f.tempPath()) << "content";
        fs::remove(f.tempPath());
        f.commit();
        ADD_FAILURE() << "no error";
    } catch (const IoError& e) {
        EXPECT_EQ(std::string(e.what()),
                  p.string() +
                      ": could not rename the finished map into place: No such file or "
                      "directory");
    }
    EXPECT_FALSE(fs::exists(p));
}

}  // namespace
}  // namespace palp
