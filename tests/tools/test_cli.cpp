#include <gtest/gtest.h>

#include <fstream>

#include "test_support.h"

namespace {

using palp::test::runCommand;

TEST(Cli, UnknownFormatIsAClearErrorAndWritesNothing) {
    palp::test::TempDir tmp;
    { std::ofstream(tmp / "notes.txt") << "hello, not a scan\n"; }
    const auto r = runCommand(palp::test::palpTool().string() + " convert " +
                              (tmp / "notes.txt").string() + " -o " + (tmp / "out.vdb").string());
    EXPECT_NE(r.exitCode, 0);
    EXPECT_NE(r.output.find("palp: error: " + (tmp / "notes.txt").string()), std::string::npos)
        << r.output;
    EXPECT_NE(r.output.find("unknown format"), std::string::npos) << r.output;
    EXPECT_FALSE(std::filesystem::exists(tmp / "out.vdb"));
}

TEST(Cli, MissingInputIsAClearError) {
    palp::test::TempDir tmp;
    const auto r = runCommand(palp::test::palpTool().string() + " convert " +
                              (tmp / "nope.nii").string() + " -o " + (tmp / "out.vdb").string());
    EXPECT_NE(r.exitCode, 0);
    EXPECT_NE(r.output.find("nope.nii: expected an existing file"), std::string::npos) << r.output;
}

TEST(Cli, UnwritableOutputDirectoryIsRefusedBeforeWork) {
    palp::test::TempDir tmp;
    { std::ofstream(tmp / "notes.txt") << "x"; }
    const auto r =
        runCommand(palp::test::palpTool().string() + " convert " + (tmp / "notes.txt").string() +
                   " -o " + (tmp / "no" / "such" / "dir.vdb").string());
    EXPECT_NE(r.exitCode, 0);
    EXPECT_NE(r.output.find("palp: error: "), std::string::npos) << r.output;
    EXPECT_NE(r.output.find("dir.vdb"), std::string::npos) << r.output;
}

}  // namespace
