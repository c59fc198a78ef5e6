#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

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

// The executable links palp_volume_core alone and opens the commands module (info, phantom,
// palpate, bench, ...) only for those commands: --version and convert load neither the module
// nor the haptics stack nor OpenVDB's library, palpate loads them; convert to a Blosc file opens
// palp_volume (and OpenVDB) for load() and save(); a module that cannot be found is named in the
// error, and convert still runs without it.
TEST(Cli, ConvertRunsWithoutTheCommandsModuleOrOpenVdbTheOthersNameItWhenMissing) {
    const std::string palp = palp::test::palpTool().string();
    const auto version = runCommand("LD_DEBUG=files " + palp + " --version");
    ASSERT_EQ(version.exitCode, 0) << version.output;
    EXPECT_NE(version.output.find("palp 0.1.0"), std::string::npos) << version.output;
    EXPECT_EQ(version.output.find("libpalp_tool_commands"), std::string::npos) << version.output;
    EXPECT_EQ(version.output.find("libpalp_haptics"), std::string::npos) << version.output;
    EXPECT_EQ(version.output.find("libopenvdb"), std::string::npos) << version.output;
    palp::test::TempDir tmp;
    std::vector<float> values(6 * 5 * 4);
    for (std::size_t i = 0; i < values.size(); ++i) values[i] = static_cast<float>(i);
    palp::test::writeFile(tmp / "a.nrrd",
                          "NRRD0004\ndimension: 3\nsizes: 6 5 4\ntype: float\n"
                          "space: left-posterior-superior\nspace origin: (1,2,3)\n"
                          "space directions: (1,0,0) (0,1,0) (0,0,2)\n"
                          "endian: little\nencoding: raw\n\n" +
                              palp::test::floatsLE(values));
    const auto convert = runCommand("LD_DEBUG=files " + palp + " convert " +
                                    (tmp / "a.nrrd").string() + " -o " + (tmp / "a.vdb").string());
    ASSERT_EQ(convert.exitCode, 0) << convert.output;
    // A NRRD says no modality: the line names the format alone.
    EXPECT_NE(convert.output.find(": NRRD, voxel 1 mm, "), std::string::npos) << convert.output;
    EXPECT_EQ(convert.output.find("libopenvdb"), std::string::npos) << convert.output;
    EXPECT_EQ(convert.output.find("libpalp_volume.so"), std::string::npos) << convert.output;
    EXPECT_EQ(convert.output.find("libpalp_tool_commands"), std::string::npos) << convert.output;
    const auto blosc =
        runCommand("LD_DEBUG=files " + palp + " --quiet convert " + (tmp / "a.nrrd").string() +
                   " -o " + (tmp / "b.vdb").string() + " --compression blosc");
    ASSERT_EQ(blosc.exitCode, 0) << blosc.output;
    EXPECT_NE(blosc.output.find("libpalp_volume.so"), std::string::npos) << blosc.output;
    EXPECT_NE(blosc.output.find("libopenvdb"), std::string::npos) << blosc.output;
    const auto help = runCommand("LD_DEBUG=files " + palp + " palpate --help");
    ASSERT_EQ(help.exitCode, 0) << help.output;
    EXPECT_NE(help.output.find("libpalp_tool_commands.so"), std::string::npos) << help.output;
    EXPECT_NE(help.output.find("libpalp_haptics"), std::string::npos) << help.output;

    // libpalp_tool.so copied alone into a folder that comes first on the library path: the
    // executable looks for the module beside it, and it is not there.
    const std::filesystem::path lib = palp::test::palpTool().parent_path() / "libpalp_tool.so.0.1";
    ASSERT_TRUE(std::filesystem::exists(lib)) << lib;
    std::filesystem::copy_file(std::filesystem::canonical(lib), tmp / "libpalp_tool.so.0.1");
    const std::string env = "LD_LIBRARY_PATH=" + tmp.path().string() + " ";
    const auto palpate = runCommand(env + palp + " palpate --phantom avc --fast --seconds 0.1");
    EXPECT_EQ(palpate.exitCode, 1) << palpate.output;
    EXPECT_NE(palpate.output.find("palp: error: " + (tmp / "libpalp_tool_commands.so").string() +
                                  ": expected palp's commands library"),
              std::string::npos)
        << palpate.output;
    EXPECT_NE(palpate.output.find("cannot be loaded"), std::string::npos) << palpate.output;
    const auto info = runCommand(env + palp + " info " + (tmp / "a.vdb").string());
    EXPECT_EQ(info.exitCode, 1) << info.output;
    const auto again = runCommand(env + palp + " --quiet convert " + (tmp / "a.nrrd").string() +
                                  " -o " + (tmp / "c.vdb").string());
    EXPECT_EQ(again.exitCode, 0) << again.output;
    EXPECT_TRUE(std::filesystem::exists(tmp / "c.vdb"));
    EXPECT_EQ(runCommand(env + palp + " --version").exitCode, 0);
}

// DICOM is read by a library of its own (GDCM behind it), opened the first time a DICOM input
// is read: a NIfTI conversion loads neither it nor GDCM, and without it a DICOM conversion stops
// naming the file palp looked for, writing nothing.
TEST(Cli, NiftiConvertsWithoutTheDicomLibraryDicomNamesItWhenMissing) {
    PALP_REQUIRE_DATA(nifti, "nifti-mr");
    PALP_REQUIRE_DATA(dicom, "ct-ge-head-tilt");
    const std::string palp = palp::test::palpTool().string();
    palp::test::TempDir tmp;
    const auto nii =
        runCommand("LD_DEBUG=files " + palp + " --quiet convert " +
                   (nifti / "anatomical.nii").string() + " -o " + (tmp / "anat.vdb").string());
    ASSERT_EQ(nii.exitCode, 0) << nii.output;
    EXPECT_EQ(nii.output.find("libpalp_volume_dicom"), std::string::npos) << nii.output;
    EXPECT_EQ(nii.output.find("libgdcm"), std::string::npos) << nii.output;

    // libpalp_volume_core.so copied alone into a folder that comes first on the library path:
    // it looks for the DICOM library beside itself, and it is not there.
    const std::filesystem::path lib = palp::test::palpTool().parent_path().parent_path() /
                                      "volume" / "libpalp_volume_core.so.0.1";
    ASSERT_TRUE(std::filesystem::exists(lib)) << lib;
    std::filesystem::copy_file(std::filesystem::canonical(lib), tmp / "libpalp_volume_core.so.0.1");
    const std::string env = "LD_LIBRARY_PATH=" + tmp.path().string() + " ";
    const auto dcm = runCommand(env + palp + " --quiet convert " + dicom.string() + " -o " +
                                (tmp / "head.vdb").string() + " --voxel-size 2");
    EXPECT_EQ(dcm.exitCode, 1) << dcm.output;
    EXPECT_NE(dcm.output.find("palp: error: " + (tmp / "libpalp_volume_dicom.so").string() +
                              ": expected palp's DICOM library, found it cannot be loaded"),
              std::string::npos)
        << dcm.output;
    EXPECT_FALSE(std::filesystem::exists(tmp / "head.vdb"));
    const auto again =
        runCommand(env + palp + " --quiet convert " + (nifti / "anatomical.nii").string() + " -o " +
                   (tmp / "anat2.vdb").string());
    EXPECT_EQ(again.exitCode, 0) << again.output;
}

// A press reaches the surface only after the session's start-up gate (50 quiet ticks) has
// opened: a press that started 5 mm out met the surface 27 ms in at 300 mm/s (45 ms at the
// default 100 mm/s on the head CT), the gate stayed shut under the force it then felt, and the
// whole press rendered 0 N. Now it starts 0.15 s of its speed out: the force is k x depth less
// the hand's give, and the report says when the target reached the surface.
TEST(Cli, PalpatePressStartsFarEnoughOutForTheStartupGate) {
    const auto r = runCommand(palp::test::palpTool().string() +
                              " palpate --phantom avc --fast --trajectory press --depth 3"
                              " --k-base 800 --speed 300 --json");
    ASSERT_EQ(r.exitCode, 0) << r.output;
    const auto brace = r.output.find('{');
    ASSERT_NE(brace, std::string::npos) << r.output;
    const auto j = nlohmann::json::parse(r.output.substr(brace), nullptr, false);
    ASSERT_FALSE(j.is_discarded()) << r.output;
    EXPECT_GT(j["max_force_n"].get<double>(), 1.5);           // ~800 N/m x 3 mm, less the give
    EXPECT_LE(j["max_force_n"].get<double>(), 3.3);           // the Touch's maximum
    EXPECT_GT(j["path_pressed_from_s"].get<double>(), 0.05);  // after the gate's 50 ms
}

// `palp palpate --deformable` presses the bone phantom with the same coupling on the whole-mesh
// explicit solver and on the asynchronous regions (synchronous, as --fast runs them): the press
// does not move the contact, so both solve the same tissue and must feel the same.
TEST(Cli, PalpateDeformableRegionsAgreeWithTheWholeMesh) {
    auto run = [](const std::string& solver) {
        const auto r = runCommand(palp::test::palpTool().string() +
                                  " palpate --phantom bone --deformable --fem-solver " + solver +
                                  " --fast --trajectory press --seconds 2 --k-base 50 --json");
        EXPECT_EQ(r.exitCode, 0) << r.output;
        const auto brace = r.output.find('{');
        EXPECT_NE(brace, std::string::npos) << r.output;
        if (brace == std::string::npos) return nlohmann::json::object();
        const auto j = nlohmann::json::parse(r.output.substr(brace), nullptr, false);
        EXPECT_FALSE(j.is_discarded()) << r.output;
        return j.is_discarded() ? nlohmann::json::object() : j;
    };
    const auto whole = run("explicit");
    const auto regions = run("regions");
    ASSERT_TRUE(whole.contains("deformable") && regions.contains("deformable"));
    EXPECT_EQ(whole["deformable"]["solver"], "explicit");
    EXPECT_EQ(regions["deformable"]["solver"], "regions");
    const double f0 = whole["max_force_n"], f1 = regions["max_force_n"];
    const double d0 = whole["deformable"]["max_displacement_mm"];
    const double d1 = regions["deformable"]["max_displacement_mm"];
    EXPECT_GT(f0, 0.05);  // the press reaches the tissue
    EXPECT_GT(d0, 1.0);
    EXPECT_NEAR(f1, f0, 0.05 * f0);
    EXPECT_NEAR(d1, d0, 0.05 * d0);
    EXPECT_EQ(regions["faulted_ticks"], 0);
}

// A refusal found after the path is known (a map finer than 4096 pixels a side) comes before the
// run, so the trace asked for beside it is never written.
TEST(Cli, PalpateRefusesATooFineMapBeforeWritingTheTrace) {
    palp::test::TempDir tmp;
    const auto r =
        runCommand(palp::test::palpTool().string() +
                   " palpate --phantom avc --voxel-mm 2 --fast --map-pixel 0.001 --trace " +
                   (tmp / "t.csv").string() + " --map " + (tmp / "m.png").string());
    EXPECT_EQ(r.exitCode, 1) << r.output;
    EXPECT_NE(r.output.find("--map-pixel: expected at least"), std::string::npos) << r.output;
    EXPECT_FALSE(std::filesystem::exists(tmp / "t.csv"));
    EXPECT_FALSE(std::filesystem::exists(tmp / "m.png"));
}

// A surface stiffness above the default clamp raises the clamp (the device's limit then lowers
// both, as reported) instead of a refusal about k_max, which the user never set; a clamp below
// a surface stiffness the user gave is refused naming both.
TEST(Cli, PalpateKBaseAboveTheDefaultClampIsNotRefusedForAClampNeverSet) {
    const std::string base = palp::test::palpTool().string() +
                             " palpate --phantom avc --voxel-mm 2 --fast --seconds 0.05 ";
    const auto ok = runCommand(base + "--k-base 5000");
    EXPECT_EQ(ok.exitCode, 0) << ok.output;
    EXPECT_EQ(ok.output.find("maxStiffness"), std::string::npos) << ok.output;
    const auto both = runCommand(base + "--k-base 800 --k-max 500");
    EXPECT_EQ(both.exitCode, 1) << both.output;
    EXPECT_NE(both.output.find("--k-max: expected a clamp >= --k-base (800 N/m)"),
              std::string::npos)
        << both.output;
}

}  // namespace
