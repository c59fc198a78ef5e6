// Tests of the raw-data helpers shared by the format readers.
#include <fcntl.h>
#include <gtest/gtest.h>
#include <unistd.h>
#include <zlib.h>

#include <cstring>
#include <fstream>
#include <limits>

#include "formats/raw_data.h"
#include "palp/base/error.h"
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

namespace {

/// Compressible bytes with structure at several scales (runs, ramps, noise), so deflate makes
/// blocks of varied lengths whose boundaries mostly fall inside a byte.
std::string structuredBytes(std::size_t n) {
    std::string s(n, '\0');
    std::uint32_t x = 12345;
    for (std::size_t i = 0; i < n; ++i) {
        x = x * 1103515245u + 12345u;
        const std::size_t region = (i >> 14) % 4;
        const unsigned v = region == 0   ? 7u
                           : region == 1 ? static_cast<unsigned>(i % 251)
                           : region == 2 ? (x >> 16) & 0xffu
                                         : static_cast<unsigned>((i / 3) % 17) + ((x >> 20) & 3u);
        s[i] = static_cast<char>(v);
    }
    return s;
}

}  // namespace

TEST(RawData, AnIndexedStreamGivesAnyRangeOfItsBytes) {
    palp::test::TempDir tmp;
    const std::string data = structuredBytes(std::size_t{3} << 20);
    for (const bool gzip : {true, false}) {
        SCOPED_TRACE(gzip ? "gzip" : "zlib");
        const std::string header = "a header of 23 bytes...";
        const auto file = tmp / (gzip ? "d.gz" : "d.z");
        palp::test::writeFile(file, header + palp::test::deflateBytes(data, gzip));
        const InflateIndex index =
            indexFileStream(file, header.size(), std::numeric_limits<std::uint64_t>::max(),
                            data.size(), 0, data.size(), false, std::uint64_t{1} << 17);
        ASSERT_TRUE(index.singleMember);
        // Points about 128 KiB apart, each with the window before it; most mid-byte.
        EXPECT_GE(index.points.size(), 12u);
        EXPECT_LE(index.points.size(), 25u);
        int midByte = 0;
        for (const auto& p : index.points) {
            EXPECT_EQ(p.window.size(), std::min<std::uint64_t>(p.out, 32768));
            midByte += p.bits > 0;
        }
        EXPECT_GT(midByte, 0);
        const int fd = ::open(file.c_str(), O_RDONLY);
        ASSERT_GE(fd, 0);
        std::uint32_t x = 99;
        const std::size_t n = data.size();
        std::vector<std::pair<std::size_t, std::size_t>> ranges = {
            {0, 1}, {0, n}, {n - 1, 1}, {n - 70000, 70000}, {131072, 262144}};
        for (const auto& p : index.points) ranges.push_back({p.out, 1000});  // at each point
        for (int i = 0; i < 40; ++i) {
            x = x * 1664525u + 1013904223u;
            const std::size_t from = x % n;
            x = x * 1664525u + 1013904223u;
            ranges.push_back({from, 1 + x % std::min<std::size_t>(n - from, 400000)});
        }
        for (const auto& [from, count] : ranges) {
            std::vector<std::byte> out(count);
            inflateAt(index, fd, from, out);
            ASSERT_EQ(std::memcmp(out.data(), data.data() + from, count), 0)
                << "bytes " << from << " + " << count;
        }
        // Points for a window only: the last before it and those inside it.
        const std::uint64_t from = 1000000, count = 700000;
        const InflateIndex part =
            indexFileStream(file, header.size(), std::numeric_limits<std::uint64_t>::max(),
                            data.size(), from, count, false, std::uint64_t{1} << 17);
        ASSERT_GE(part.points.size(), 4u);
        EXPECT_LE(part.points.size(), 8u);
        EXPECT_LE(part.points.front().out, from);
        EXPECT_GT(part.points[1].out, from);
        EXPECT_LT(part.points.back().out, from + count);
        std::vector<std::byte> out(count);
        inflateAt(part, fd, from, out);
        EXPECT_EQ(std::memcmp(out.data(), data.data() + from, count), 0);
        ::close(fd);
    }
    // Two gzip members: checked like one stream, but no random access.
    const std::string two = palp::test::deflateBytes(data.substr(0, 1000000), true) +
                            palp::test::deflateBytes(data.substr(1000000), true);
    palp::test::writeFile(tmp / "two.gz", two);
    const InflateIndex twoIndex =
        indexFileStream(tmp / "two.gz", 0, std::numeric_limits<std::uint64_t>::max(), data.size(),
                        0, data.size(), false, 1 << 17);
    EXPECT_FALSE(twoIndex.singleMember);
    // A damaged stream is refused while indexing, as when its bytes are kept.
    std::string bad = palp::test::deflateBytes(data, true);
    bad[bad.size() / 2] = static_cast<char>(bad[bad.size() / 2] ^ 0x5a);
    palp::test::writeFile(tmp / "bad.gz", bad);
    palp::test::expectThrowWith<palp::FormatError>(
        [&] {
            (void)indexFileStream(tmp / "bad.gz", 0, std::numeric_limits<std::uint64_t>::max(),
                                  data.size(), 0, data.size(), false, 1 << 17);
        },
        {"bad.gz"});
}
