#include "palp/studies/map_png.h"

#include <png.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <string>
#include <vector>

#include "palp/base/atomic_file.h"
#include "palp/base/error.h"

namespace palp::haptics {

namespace {

std::array<std::uint8_t, 3> heat(double s) {
    // Black -> red -> yellow -> white, piecewise linear in thirds.
    s = std::clamp(s, 0.0, 1.0);
    const auto c = [](double x) {
        return static_cast<std::uint8_t>(std::lround(255.0 * std::clamp(x, 0.0, 1.0)));
    };
    return {c(3 * s), c(3 * s - 1), c(3 * s - 2)};
}

// The image of @p map: @p channels (1 grey, 3 RGB) bytes per pixel, rows from the top (the
// largest v), each map pixel repeated scale x scale times.
std::vector<std::uint8_t> mapPixels(const ScalarMap& map, const PngOptions& options, int channels) {
    double lo = options.lo, hi = options.hi;
    double mn = 0, mx = 0;
    map.range(mn, mx);
    if (!std::isfinite(lo)) lo = mn;
    if (!std::isfinite(hi)) hi = mx;
    const double span = (std::isfinite(lo) && std::isfinite(hi) && hi > lo) ? hi - lo : 1.0;
    const bool rgb = channels == 3;
    const int scale = options.scale;
    const int width = map.cols() * scale, height = map.rows() * scale;
    std::vector<std::uint8_t> pixels(static_cast<std::size_t>(width) *
                                     static_cast<std::size_t>(height) *
                                     static_cast<std::size_t>(channels));
    for (int y = 0; y < height; ++y) {
        const int row = map.rows() - 1 - y / scale;  // image row 0 = largest v
        for (int x = 0; x < width; ++x) {
            const double value = map.at(x / scale, row);
            std::uint8_t* p =
                &pixels[(static_cast<std::size_t>(y) * static_cast<std::size_t>(width) +
                         static_cast<std::size_t>(x)) *
                        static_cast<std::size_t>(channels)];
            if (!std::isfinite(value)) {
                if (rgb) {
                    p[0] = 0;
                    p[1] = 0;
                    p[2] = 64;
                } else {
                    p[0] = 0;
                }
                continue;
            }
            const double s = std::isfinite(lo) ? (value - lo) / span : 0.0;
            if (rgb) {
                const auto c = heat(s);
                p[0] = c[0];
                p[1] = c[1];
                p[2] = c[2];
            } else {
                p[0] = static_cast<std::uint8_t>(std::lround(255.0 * std::clamp(s, 0.0, 1.0)));
            }
        }
    }
    return pixels;
}

void appendBytes(png_structp png, png_bytep data, png_size_t size) {
    auto* out = static_cast<std::string*>(png_get_io_ptr(png));
    out->append(reinterpret_cast<const char*>(data), size);
}

void flushNothing(png_structp) {}

// Encodes 8-bit rows (grey or RGB) as a PNG into @p out; false when libpng fails. libpng
// reports errors by longjmp, so this frame holds only trivially destructible objects.
bool encodePng(std::string* out, png_bytep* rows, int width, int height, int channels) {
    png_structp png = png_create_write_struct(PNG_LIBPNG_VER_STRING, nullptr, nullptr, nullptr);
    if (png == nullptr) return false;
    png_infop info = png_create_info_struct(png);
    if (info == nullptr) {
        png_destroy_write_struct(&png, nullptr);
        return false;
    }
    if (setjmp(png_jmpbuf(png))) {
        png_destroy_write_struct(&png, &info);
        return false;
    }
    png_set_write_fn(png, out, appendBytes, flushNothing);
    png_set_IHDR(png, info, static_cast<png_uint_32>(width), static_cast<png_uint_32>(height), 8,
                 channels == 3 ? PNG_COLOR_TYPE_RGB : PNG_COLOR_TYPE_GRAY, PNG_INTERLACE_NONE,
                 PNG_COMPRESSION_TYPE_DEFAULT, PNG_FILTER_TYPE_DEFAULT);
    png_set_rows(png, info, rows);
    png_write_png(png, info, PNG_TRANSFORM_IDENTITY, nullptr);
    png_destroy_write_struct(&png, &info);
    return true;
}

}  // namespace

void writeMapPng(const std::filesystem::path& path, const ScalarMap& map,
                 const PngOptions& options) {
    if (options.scale < 1 || options.scale > 16) {
        throw ValueError("map PNG: expected a scale of 1-16, found " +
                         std::to_string(options.scale));
    }
    const int channels = options.colorMap == ColorMap::Heat ? 3 : 1;
    const int width = map.cols() * options.scale, height = map.rows() * options.scale;
    std::vector<std::uint8_t> pixels = mapPixels(map, options, channels);
    std::vector<png_bytep> rows(static_cast<std::size_t>(height));
    for (std::size_t y = 0; y < rows.size(); ++y) {
        rows[y] = pixels.data() +
                  y * static_cast<std::size_t>(width) * static_cast<std::size_t>(channels);
    }
    std::string bytes;
    if (!encodePng(&bytes, rows.data(), width, height, channels)) {
        throw IoError(path.string() + ": expected to encode a " + std::to_string(width) + "x" +
                      std::to_string(height) + " PNG, the encoder failed");
    }
    palp::writeFileAtomically(path, "map PNG", bytes.data(), bytes.size());
}

}  // namespace palp::haptics
