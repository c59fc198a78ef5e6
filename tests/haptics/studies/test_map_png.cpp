// Map images: pixel layout, value scaling and colour maps of writeMapPng(), read back with
// libpng; atomic writes.
#include <gtest/gtest.h>
#include <png.h>

#include <filesystem>
#include <string>
#include <vector>

#include "palp/base/error.h"
#include "palp/studies/map_png.h"

namespace palp::haptics {
namespace {

namespace fs = std::filesystem;

fs::path tempDir(const std::string& name) {
    fs::path d = fs::temp_directory_path() / ("palp_test_map_png_" + name);
    fs::remove_all(d);
    fs::create_directories(d);
    return d;
}

// Decodes the PNG at @p path with libpng into @p channels (1 grey, 3 RGB) bytes per pixel, rows
// from the top; @p fileChannels receives the channels stored in the file. Empty on failure.
std::vector<unsigned char> readPng(const fs::path& path, int channels, int& w, int& h,
                                   int& fileChannels) {
    png_image image{};
    image.version = PNG_IMAGE_VERSION;
    if (!png_image_begin_read_from_file(&image, path.c_str())) return {};
    fileChannels = static_cast<int>(PNG_IMAGE_SAMPLE_CHANNELS(image.format));
    image.format = channels == 3 ? PNG_FORMAT_RGB : PNG_FORMAT_GRAY;
    std::vector<unsigned char> pixels(PNG_IMAGE_SIZE(image));
    if (!png_image_finish_read(&image, nullptr, pixels.data(), 0, nullptr)) {
        png_image_free(&image);
        return {};
    }
    w = static_cast<int>(image.width);
    h = static_cast<int>(image.height);
    return pixels;
}

TEST(MapPng, WritesTopRowAsLargestVAndScalesValues) {
    const fs::path dir = tempDir("png");
    MapPlane p;
    p.extentU = 0.003;
    p.extentV = 0.002;
    p.pixelM = 0.001;  // 3 x 2
    ScalarMap m(p);
    m.set(0, 0, 0.0);   // bottom-left: darkest
    m.set(2, 1, 10.0);  // top-right: brightest
    m.set(1, 1, 5.0);
    PngOptions o;
    o.colorMap = ColorMap::Grey;
    o.scale = 2;
    writeMapPng(dir / "m.png", m, o);
    int w = 0, h = 0, n = 0;
    std::vector<unsigned char> pixels = readPng(dir / "m.png", 1, w, h, n);
    ASSERT_FALSE(pixels.empty());
    const unsigned char* img = pixels.data();
    EXPECT_EQ(w, 6);
    EXPECT_EQ(h, 4);
    auto px = [&](int x, int y) { return static_cast<int>(img[y * w + x]); };
    EXPECT_EQ(px(5, 0), 255);  // top-right image pixel = (col 2, row 1)
    EXPECT_EQ(px(4, 1), 255);
    EXPECT_EQ(px(0, 3), 0);         // bottom-left = (col 0, row 0), value 0
    EXPECT_NEAR(px(2, 0), 128, 1);  // (col 1, row 1) = 5 of 0..10
    EXPECT_EQ(px(0, 0), 0);         // empty pixel (col 0, row 1): black
    // Heat: RGB, brightest white.
    writeMapPng(dir / "h.png", m, PngOptions{});
    pixels = readPng(dir / "h.png", 3, w, h, n);
    ASSERT_FALSE(pixels.empty());
    img = pixels.data();
    EXPECT_EQ(n, 3);
    EXPECT_EQ(img[(0 * w + 2) * 3 + 0], 255);
    EXPECT_EQ(img[(0 * w + 2) * 3 + 2], 255);
    // A missing directory: IoError naming it, nothing left behind.
    try {
        writeMapPng(dir / "no" / "m.png", m);
        FAIL() << "expected an IoError";
    } catch (const IoError& e) {
        EXPECT_NE(std::string(e.what()).find("no"), std::string::npos);
    }
    std::size_t files = 0;
    for ([[maybe_unused]] const auto& e : fs::directory_iterator(dir)) ++files;
    EXPECT_EQ(files, 2u);
    o.scale = 0;
    EXPECT_THROW(writeMapPng(dir / "bad.png", m, o), ValueError);
    fs::remove_all(dir);
}

}  // namespace
}  // namespace palp::haptics
