// Tests of the raw-data helpers shared by the format readers.
#include <gtest/gtest.h>
#include <zlib.h>

#include <cstring>
#include <fstream>
#include <limits>

#include "palp/base/error.h"
#include "raw_data.h"
#include "test_support.h"

namespace {

using namespace palp::volume;

std::vector<std::byte> bytesOf(const std::vector<unsigned char>& v) {
    std::vector<std::byte> out;
    for (const unsigned char c : v) out.push_back(static_cast<std::byte>(c));
    return out;
}

TEST(RawData, DecodesEveryTypeInBothByteOrders) {
    std::vector<float> out(1);
    decodeElements(bytesOf({0xff}), ElementType::Int8, ByteOrder::Little, out);
    EXPECT_EQ(out[0], -1.0f);
    decodeElements(bytesOf({0xff}), ElementType::UInt8, ByteOrder::Big, out);
    EXPECT_EQ(out[0], 255.0f);
    decodeElements(bytesOf({0x01, 0x02}), ElementType::Int16, ByteOrder::Little, out);
    EXPECT_EQ(out[0], 513.0f);
    decodeElements(bytesOf({0x01, 0x02}), ElementType::Int16, ByteOrder::Big, out);
    EXPECT_EQ(out[0], 258.0f);
    decodeElements(bytesOf({0xff, 0xfe}), ElementType::Int16, ByteOrder::Big, out);
    EXPECT_EQ(out[0], -2.0f);
    decodeElements(bytesOf({0xff, 0xfe}), ElementType::UInt16, ByteOrder::Big, out);
    EXPECT_EQ(out[0], 65534.0f);
    decodeElements(bytesOf({0x00, 0x01, 0x00, 0x00}), ElementType::Int32, ByteOrder::Big, out);
    EXPECT_EQ(out[0], 65536.0f);
    decodeElements(bytesOf({0xff, 0xff, 0xff, 0xff}), ElementType::UInt32, ByteOrder::Little, out);
    EXPECT_EQ(out[0], 4294967295.0f);
    decodeElements(bytesOf({0xff, 0xff, 0xff, 0xff, 0xff, 0xff, 0xff, 0xfd}), ElementType::Int64,
                   ByteOrder::Big, out);
    EXPECT_EQ(out[0], -3.0f);
    decodeElements(bytesOf({0, 0, 0, 0, 0, 0, 0, 0x80}), ElementType::UInt64, ByteOrder::Little,
                   out);
    EXPECT_EQ(out[0], 9223372036854775808.0f);
    decodeElements(bytesOf({0x3f, 0xc0, 0x00, 0x00}), ElementType::Float32, ByteOrder::Big, out);
    EXPECT_EQ(out[0], 1.5f);
    decodeElements(bytesOf({0, 0, 0, 0, 0, 0, 0x04, 0xc0}), ElementType::Float64, ByteOrder::Little,
                   out);
    EXPECT_EQ(out[0], -2.5f);
    EXPECT_THROW(decodeElements(bytesOf({1, 2, 3}), ElementType::Int32, ByteOrder::Little, out),
                 palp::ValueError);
    EXPECT_EQ(elementSize(ElementType::UInt64), 8u);
    EXPECT_STREQ(elementTypeName(ElementType::Float32), "float32");
}

TEST(RawData, CheckedSizesRefuseOverflowAndLimit) {
    const std::vector<std::int64_t> dims{64, 64, 37};
    EXPECT_EQ(checkedDataBytes(dims, 2, 1 << 20, "x"), 64u * 64u * 37u * 2u);
    const std::vector<std::int64_t> big{std::int64_t{1} << 32, std::int64_t{1} << 32, 2};
    try {
        checkedDataBytes(big, 1, std::numeric_limits<std::uint64_t>::max(), "f.nrrd");
        ADD_FAILURE() << "overflow not detected";
    } catch (const palp::ValueError& e) {
        EXPECT_NE(std::string(e.what()).find("f.nrrd: expected at most"), std::string::npos)
            << e.what();
        EXPECT_NE(std::string(e.what()).find("more than 2^64"), std::string::npos) << e.what();
    }
    EXPECT_THROW(checkedDataBytes(dims, 2, 1000, "x"), palp::ValueError);
    const std::vector<std::int64_t> zero{4, 0, 4};
    EXPECT_THROW(checkedDataBytes(zero, 2, 1000, "x"), palp::ValueError);
    const std::vector<std::int64_t> negative{4, -3, 4};
    EXPECT_THROW(checkedDataBytes(negative, 2, 1000, "x"), palp::ValueError);
}

TEST(RawData, InflateIsExactAboutTheExpectedSize) {
    std::vector<unsigned char> plain(3'000'000);
    for (std::size_t i = 0; i < plain.size(); ++i)
        plain[i] = static_cast<unsigned char>((i * 7) ^ (i >> 9));
    uLongf zsize = compressBound(static_cast<uLong>(plain.size()));
    std::vector<unsigned char> z(zsize);
    ASSERT_EQ(compress2(z.data(), &zsize, plain.data(), static_cast<uLong>(plain.size()), 6), Z_OK);
    z.resize(zsize);
    const std::span<const std::byte> zs(reinterpret_cast<const std::byte*>(z.data()), z.size());
    const auto out = inflateBytes(zs, plain.size(), "z");
    ASSERT_EQ(out.size(), plain.size());
    EXPECT_EQ(std::memcmp(out.data(), plain.data(), plain.size()), 0);
    EXPECT_THROW(inflateBytes(zs, plain.size() + 1, "z"), palp::FormatError);  // stream shorter
    EXPECT_THROW(inflateBytes(zs, plain.size() - 1, "z"), palp::FormatError);  // stream longer
    EXPECT_THROW(inflateBytes(zs.first(zs.size() / 2), plain.size(), "z"),
                 palp::FormatError);  // truncated
    std::vector<std::byte> garbage(100, std::byte{0x42});
    EXPECT_THROW(inflateBytes(garbage, 10, "z"), palp::FormatError);
}

TEST(RawData, FileRangesAreCheckedBeforeReading) {
    palp::test::TempDir tmp;
    const auto file = tmp / "d.bin";
    {
        std::ofstream out(file, std::ios::binary);
        out << "0123456789";
    }
    EXPECT_EQ(fileSize(file), 10u);
    const auto r = readFileRange(file, 3, 4);
    EXPECT_EQ(static_cast<char>(r[0]), '3');
    EXPECT_EQ(static_cast<char>(r[3]), '6');
    try {
        readFileRange(file, 4, 1234567);
        ADD_FAILURE();
    } catch (const palp::FormatError& e) {
        EXPECT_NE(std::string(e.what()).find(
                      file.string() + ": expected 1234567 bytes of voxel data after the header"),
                  std::string::npos)
            << e.what();
        EXPECT_NE(std::string(e.what()).find("found 6"), std::string::npos) << e.what();
    }
    EXPECT_THROW(fileSize(tmp / "missing"), palp::IoError);
    EXPECT_EQ(skipLines(file, 0, 0), 0u);
    EXPECT_THROW(skipLines(file, 0, 1), palp::FormatError);
}

}  // namespace
