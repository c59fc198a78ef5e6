// The C API's volume entry points (palp_volume_load, palp_volume_make_phantom,
// palp_scene_from_volume) with every hostile number (issue 20): nan, inf, -inf, -1, 0 and 1e300
// give PALP_ERROR_INVALID_ARGUMENT with a message naming the C field, never
// PALP_ERROR_INTERNAL (reserved for bugs), and never a handle.
#include <gtest/gtest.h>

#include <fstream>
#include <limits>
#include <string>
#include <utility>

#include "palp/palp.h"
#include "test_support.h"

namespace {

constexpr double kNan = std::numeric_limits<double>::quiet_NaN();
constexpr double kInf = std::numeric_limits<double>::infinity();

TEST(CApiVolume, MakePhantomRefusesEveryBadVoxelSizeNamingVoxelSize) {
    for (const double bad : {kNan, kInf, -kInf, -1.0, 0.0, 1e300, 1e-300}) {
        palp_volume* volume = nullptr;
        EXPECT_EQ(palp_volume_make_phantom("avc", 0, nullptr, bad, &volume),
                  PALP_ERROR_INVALID_ARGUMENT)
            << bad;
        EXPECT_EQ(volume, nullptr);
        const std::string m = palp_last_error();
        EXPECT_EQ(
            m.rfind("palp_volume_make_phantom: voxel_size: expected a value in [1e-06, 0.1] m", 0),
            0u)
            << m;
    }
}

TEST(CApiVolume, LoadRefusesEveryBadVoxelSizeNamingVoxelSize) {
    palp::test::TempDir tmp;
    const auto file = tmp / "s.nrrd";
    {
        std::ofstream out(file, std::ios::binary);
        out << "NRRD0004\ntype: uchar\ndimension: 3\nsizes: 2 2 2\nspacings: 1 1 1\n"
               "encoding: raw\n\n";
        out.write("\x00\x01\x02\x03\x04\x05\x06\x07", 8);
    }
    for (const double bad : {kNan, kInf, -kInf, -1.0, 1e300, 1e-300}) {
        palp_volume* volume = nullptr;
        EXPECT_EQ(palp_volume_load(file.c_str(), bad, &volume), PALP_ERROR_INVALID_ARGUMENT) << bad;
        EXPECT_EQ(volume, nullptr);
        const std::string m = palp_last_error();
        EXPECT_EQ(m.rfind("palp_volume_load: voxel_size (0: the finest input spacing): expected "
                          "a value in [1e-06, 0.1] m",
                          0),
                  0u)
            << m;
    }
    // 0 is the documented default; a voxel size in bounds is honoured.
    palp_volume* volume = nullptr;
    ASSERT_EQ(palp_volume_load(file.c_str(), 0.0, &volume), PALP_OK) << palp_last_error();
    double voxel = 0;
    ASSERT_EQ(palp_volume_geometry(volume, &voxel, nullptr, nullptr), PALP_OK);
    EXPECT_NEAR(voxel, 1e-3, 1e-12);
    palp_volume_release(volume);
    ASSERT_EQ(palp_volume_load(file.c_str(), 0.5e-3, &volume), PALP_OK) << palp_last_error();
    ASSERT_EQ(palp_volume_geometry(volume, &voxel, nullptr, nullptr), PALP_OK);
    EXPECT_NEAR(voxel, 0.5e-3, 1e-12);
    palp_volume_release(volume);
}

TEST(CApiVolume, AFileWithABadSpacingIsAFormatErrorNamingFileAndField) {
    palp::test::TempDir tmp;
    const auto file = tmp / "zero.nrrd";
    {
        std::ofstream out(file, std::ios::binary);
        out << "NRRD0004\ntype: uchar\ndimension: 3\nsizes: 2 2 2\nspacings: 0 0 0\n"
               "encoding: raw\n\n";
        out.write("\x00\x01\x02\x03\x04\x05\x06\x07", 8);
    }
    palp_volume* volume = nullptr;
    EXPECT_EQ(palp_volume_load(file.c_str(), 0.0, &volume), PALP_ERROR_FORMAT);
    EXPECT_EQ(volume, nullptr);
    const std::string m = palp_last_error();
    EXPECT_NE(m.find(file.string() + ": spacings (axis 0): expected a finite non-zero spacing"),
              std::string::npos)
        << m;
}

TEST(CApiVolume, SceneFromVolumeRefusesBadIsoValuesNamingTheFieldAndTakesNanAsNone) {
    palp_volume* volume = nullptr;
    ASSERT_EQ(palp_volume_make_phantom("avc", 0, nullptr, 2e-3, &volume), PALP_OK)
        << palp_last_error();
    // NAN leaves an iso-surface out (palp.h): accepted.
    for (const auto& [surface, hard] : {std::pair{kNan, 500.0}, std::pair{-500.0, kNan}}) {
        palp_scene* scene = nullptr;
        EXPECT_EQ(palp_scene_from_volume(volume, surface, hard, &scene), PALP_OK)
            << palp_last_error();
        EXPECT_NE(scene, nullptr);
        palp_scene_release(scene);
    }
    for (const double bad : {kInf, -kInf, 1e300, -1e300}) {
        palp_scene* scene = nullptr;
        EXPECT_EQ(palp_scene_from_volume(volume, bad, 500.0, &scene), PALP_ERROR_INVALID_ARGUMENT);
        EXPECT_EQ(scene, nullptr);
        EXPECT_EQ(std::string(palp_last_error())
                      .rfind("palp_scene_from_volume: surface_iso (NAN: none): expected", 0),
                  0u)
            << palp_last_error();
        EXPECT_EQ(palp_scene_from_volume(volume, -500.0, bad, &scene), PALP_ERROR_INVALID_ARGUMENT);
        EXPECT_EQ(scene, nullptr);
        EXPECT_EQ(std::string(palp_last_error())
                      .rfind("palp_scene_from_volume: hard_iso (NAN: none): expected", 0),
                  0u)
            << palp_last_error();
    }
    palp_volume_release(volume);
}

}  // namespace
