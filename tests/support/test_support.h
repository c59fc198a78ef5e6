#pragma once
/// @file
/// Helpers shared by palp's tests: data folders, temporary directories, running the palp tool.

#include <filesystem>
#include <string>

namespace palp::test {

/// `../shared/data` (or $PALP_DATA_DIR). Empty path when absent.
std::filesystem::path dataDir();

/// Calls GTEST_SKIP-worthy check: returns the path of @p sub inside dataDir(), or empty when the
/// folder is not there.
std::filesystem::path dataPath(const std::string& sub);

/// A fresh directory under the system temp dir, removed by the destructor.
class TempDir {
  public:
    TempDir();
    ~TempDir();
    TempDir(const TempDir&) = delete;
    TempDir& operator=(const TempDir&) = delete;
    const std::filesystem::path& path() const { return mPath; }
    std::filesystem::path operator/(const std::string& name) const { return mPath / name; }

  private:
    std::filesystem::path mPath;
};

/// Result of running a command.
struct RunResult {
    int exitCode = -1;
    std::string output;  ///< stdout and stderr together
};

/// Runs a shell command line, capturing output.
RunResult runCommand(const std::string& commandLine);

/// Path of the built palp tool ($PALP_BIN_DIR/tools/palp).
std::filesystem::path palpTool();

/// True when @p program is on PATH.
bool haveProgram(const std::string& program);

}  // namespace palp::test

/// Skips the current test when the shared data folder @p sub is missing.
#define PALP_REQUIRE_DATA(var, sub)                                \
    const std::filesystem::path var = ::palp::test::dataPath(sub); \
    if (var.empty()) GTEST_SKIP() << "shared data folder '" << (sub) << "' not found"
