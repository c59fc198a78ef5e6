// Stored DICOM pixel values to rescaled floats (convertFrame): every stored-bits layout against
// the definition (the stored bits, sign-extended from the high bit when signed, times the slope
// plus the intercept, rounded to float, beyond float range infinite), bits above the high bit
// (overlays) ignored.
#include <gdcmPixelFormat.h>
#include <gtest/gtest.h>

#include <cmath>
#include <cstdint>
#include <cstring>
#include <limits>
#include <vector>

#include "dicom/dicom_pixels.h"

namespace {

struct Layout {
    unsigned short bitsAllocated, bitsStored, highBit, pixelRepresentation;
};

/// The definition, in 64-bit integers and doubles.
float expected(std::uint64_t raw, const Layout& l, double slope, double intercept) {
    std::int64_t s = 0;
    if (l.bitsStored < l.bitsAllocated && l.highBit + 1 == l.bitsStored) {
        s = static_cast<std::int64_t>(raw & ((std::uint64_t{1} << l.bitsStored) - 1));
        if (l.pixelRepresentation == 1 && (s >> (l.bitsStored - 1)) & 1)
            s -= std::int64_t{1} << l.bitsStored;
    } else if (l.pixelRepresentation == 1) {
        s = l.bitsAllocated == 8 ? static_cast<std::int8_t>(raw) : static_cast<std::int16_t>(raw);
    } else {
        s = static_cast<std::int64_t>(raw);
    }
    const double v = slope * static_cast<double>(s) + intercept;
    if (std::abs(v) > static_cast<double>(std::numeric_limits<float>::max()))
        return v > 0 ? std::numeric_limits<float>::infinity()
                     : -std::numeric_limits<float>::infinity();
    return static_cast<float>(v);
}

TEST(DicomPixels, StoredBitsRescaledAsDefined) {
    const Layout layouts[] = {{16, 16, 15, 0}, {16, 16, 15, 1}, {16, 12, 11, 0}, {16, 12, 11, 1},
                              {8, 8, 7, 0},    {8, 8, 7, 1},    {8, 6, 5, 0},    {8, 6, 5, 1}};
    const double rescale[][2] = {{1, -1024}, {0.4375, -3.1}, {-2.5, 7}, {1e35, 0}};
    for (const Layout& l : layouts) {
        const gdcm::PixelFormat pf(1, l.bitsAllocated, l.bitsStored, l.highBit,
                                   l.pixelRepresentation);
        // Every stored value once (all 2^16 or 2^8 patterns, overlay bits included), so both
        // ends of the range and the sign bit are met; an odd count leaves a loop remainder.
        const std::size_t count = (std::size_t{1} << l.bitsAllocated) + 3;
        const std::size_t bytes = l.bitsAllocated / 8u;
        std::vector<char> raw(count * bytes);
        for (std::size_t i = 0; i < count; ++i) {
            const auto v = static_cast<std::uint16_t>(i * 40503u);
            std::memcpy(raw.data() + i * bytes, &v, bytes);  // little-endian host
        }
        for (const auto& [slope, intercept] : rescale) {
            SCOPED_TRACE(testing::Message() << l.bitsAllocated << "/" << l.bitsStored << " bits, "
                                            << (l.pixelRepresentation ? "signed" : "unsigned")
                                            << ", slope " << slope << ", intercept " << intercept);
            std::vector<float> out;
            const bool withinBounds = palp::volume::dicom::convertFrame(
                "f.dcm", raw.data(), pf, count, slope, intercept, out);
            ASSERT_EQ(out.size(), count);
            // The verdict that lets the loader skip the value check: given for CT-like
            // rescales, and never for values outside bounds::kVolumeValue (+-1e9).
            if (std::abs(slope) < 10) {
                EXPECT_TRUE(withinBounds);
            }
            if (withinBounds) {
                for (const float v : out) ASSERT_LE(std::abs(v), 1e9f);
            }
            if (slope > 1e30) {
                EXPECT_FALSE(withinBounds);
            }
            std::size_t wrong = 0;
            for (std::size_t i = 0; i < count; ++i) {
                std::uint64_t v = 0;
                std::memcpy(&v, raw.data() + i * bytes, bytes);
                const float e = expected(v, l, slope, intercept);
                if (!(out[i] == e)) {
                    if (wrong++ == 0)
                        ADD_FAILURE() << "pixel " << i << ": " << out[i] << " != " << e;
                }
            }
            EXPECT_EQ(wrong, 0u);
        }
    }
}

}  // namespace
