#pragma once
/// @file
/// Helpers shared by palp's tests: data folders, temporary directories, running the palp tool.

#include <gtest/gtest.h>

#include <exception>
#include <filesystem>
#include <string>
#include <vector>

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

/// Writes @p bytes to @p path (binary), replacing it.
void writeFile(const std::filesystem::path& path, const std::string& bytes);

/// @p data as a zlib stream, or a gzip one when @p gzip, at compression @p level.
std::string deflateBytes(const std::string& data, bool gzip, int level = 6);

/// @p values as little-endian float32 bytes (the test machines are x86-64).
std::string floatsLE(const std::vector<float>& values);

/// Expects @p fn to throw exactly @p E (a std::exception of another type is a failure) with a
/// message holding every string in @p parts.
template <typename E, typename Fn>
void expectThrowWith(Fn&& fn, const std::vector<std::string>& parts) {
    try {
        fn();
        ADD_FAILURE() << "expected an exception";
    } catch (const E& e) {
        const std::string msg = e.what();
        for (const auto& p : parts)
            EXPECT_NE(msg.find(p), std::string::npos) << "'" << p << "' not in: " << msg;
    } catch (const std::exception& e) {
        ADD_FAILURE() << "wrong exception type: " << e.what();
    }
}

}  // namespace palp::test

/// Skips the current test when the shared data folder @p sub is missing.
#define PALP_REQUIRE_DATA(var, sub)                                \
    const std::filesystem::path var = ::palp::test::dataPath(sub); \
    if (var.empty()) GTEST_SKIP() << "shared data folder '" << (sub) << "' not found"
