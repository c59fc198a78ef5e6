#pragma once
/// @file
/// Reading a PNG back in tests (libpng's simplified API): the map figures' pixels.

#include <png.h>

#include <cstddef>
#include <string>
#include <vector>

namespace palp::test {

/// An RGB image read back with libpng (empty on failure).
struct Rgb {
    int w = 0, h = 0;
    std::vector<unsigned char> px;
    const unsigned char* at(int x, int y) const {
        return &px[(static_cast<std::size_t>(y) * static_cast<std::size_t>(w) +
                    static_cast<std::size_t>(x)) *
                   3];
    }
    int lum(int x, int y) const { return (at(x, y)[0] + at(x, y)[1] + at(x, y)[2]) / 3; }
};

inline Rgb readPng(const std::string& path) {
    Rgb img;
    png_image image{};
    image.version = PNG_IMAGE_VERSION;
    if (!png_image_begin_read_from_file(&image, path.c_str())) return img;
    image.format = PNG_FORMAT_RGB;
    img.px.resize(PNG_IMAGE_SIZE(image));
    if (!png_image_finish_read(&image, nullptr, img.px.data(), 0, nullptr)) {
        png_image_free(&image);
        img.px.clear();
        return img;
    }
    img.w = static_cast<int>(image.width);
    img.h = static_cast<int>(image.height);
    return img;
}

}  // namespace palp::test
