// DICOM transfer syntaxes and tags the reader must name or keep: a syntax GDCM does not know
// (named with the standard's name where it has one), damaged JPEG 2000 that GDCM decodes without
// complaint, and the sign of the Gantry/Detector Tilt
// (0018,1120) in the volume's metadata. Files are made at test time from a small synthetic
// series or copies of the tilted CT in ../shared/data.
#include <gdcmImageReader.h>
#include <gdcmReader.h>
#include <gdcmWriter.h>
#include <gtest/gtest.h>
#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <functional>
#include <iterator>
#include <string>
#include <vector>

#include "palp/base/error.h"
#include "palp/volume/dicom.h"
#include "palp/volume/load.h"
#include "test_support.h"

namespace {

namespace fs = std::filesystem;
using palp::test::expectThrowWith;
using palp::test::TempDir;
using palp::volume::Slice;
using palp::volume::SliceStack;

std::string readBytes(const fs::path& p) {
    std::ifstream in(p, std::ios::binary);
    return {std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
}

std::uint32_t le32(const std::string& b, std::size_t at) {
    std::uint32_t v = 0;
    std::memcpy(&v, b.data() + at, 4);
    return v;
}

std::uint16_t le16(const std::string& b, std::size_t at) {
    std::uint16_t v = 0;
    std::memcpy(&v, b.data() + at, 2);
    return v;
}

/// A copy of the Part 10 file @p bytes whose file meta information says Transfer Syntax UID
/// @p uid (the data set is left as it is). The meta group (explicit VR little endian, as Part 10
/// requires) is rebuilt element by element so that its group length stays right.
std::string withTransferSyntax(const std::string& bytes, std::string uid) {
    if (uid.size() % 2 != 0) uid.push_back('\0');
    std::string meta;
    std::size_t at = 132;
    while (at + 8 <= bytes.size() && le16(bytes, at) == 0x0002) {
        const std::uint16_t element = le16(bytes, at + 2);
        const std::string vr = bytes.substr(at + 4, 2);
        const bool longForm = vr == "OB" || vr == "OW" || vr == "UN" || vr == "SQ" || vr == "UT";
        const std::size_t head = longForm ? 12 : 8;
        const std::size_t length = longForm ? le32(bytes, at + 8) : le16(bytes, at + 6);
        if (element == 0x0010) {
            std::string e = bytes.substr(at, 6);
            const auto n = static_cast<std::uint16_t>(uid.size());
            e.append(reinterpret_cast<const char*>(&n), 2);
            meta += e + uid;
        } else if (element != 0x0000) {
            meta += bytes.substr(at, head + length);
        }
        at += head + length;
    }
    const auto groupLength = static_cast<std::uint32_t>(meta.size());
    std::string out = bytes.substr(0, 132);
    out += std::string("\x02\x00\x00\x00UL\x04\x00", 8);
    out.append(reinterpret_cast<const char*>(&groupLength), 4);
    return out + meta + bytes.substr(at);
}

/// Two 4x4 slices written by palp's own DICOM writer into @p dir (explicit VR little endian).
std::vector<fs::path> writeSmallSeries(const fs::path& dir) {
    SliceStack stack;
    for (int k = 0; k < 2; ++k) {
        Slice s;
        s.cols = s.rows = 4;
        s.colStep = Eigen::Vector3d(1e-3, 0, 0);
        s.rowStep = Eigen::Vector3d(0, 1e-3, 0);
        s.position = Eigen::Vector3d(0, 0, 2e-3 * k);
        s.values.assign(16, static_cast<float>(100 * k));
        s.source = "slice";
        stack.slices.push_back(s);
    }
    palp::volume::writeDicomSeries(stack, dir);
    std::vector<fs::path> files;
    for (const auto& e : fs::directory_iterator(dir)) files.push_back(e.path());
    std::sort(files.begin(), files.end());
    return files;
}

TEST(DicomSyntax, TransferSyntaxGdcmDoesNotKnowIsNamedWithTheFile) {
    TempDir tmp;
    const std::vector<fs::path> files = writeSmallSeries(tmp / "series");
    ASSERT_EQ(files.size(), 2u);
    ASSERT_EQ(palp::volume::readStack({tmp / "series"}, {}).slices.size(), 2u);
    struct Case {
        std::string uid, named;
    };
    // HTJ2K came after this GDCM (PS3.6 Table A-1 names it); the second is no syntax at all.
    const Case cases[] = {
        {"1.2.840.10008.1.2.4.201",
         "1.2.840.10008.1.2.4.201 (High-Throughput JPEG 2000 Lossless, which GDCM cannot read)"},
        {"1.2.826.0.1.3680043.99.1", "1.2.826.0.1.3680043.99.1 (unknown transfer syntax)"},
    };
    for (const Case& c : cases) {
        // One file of the series in that syntax: the series is refused by that file's name.
        const fs::path dir = tmp / "mixed";
        fs::remove_all(dir);
        fs::create_directories(dir);
        fs::copy_file(files[0], dir / "a.dcm");
        palp::test::writeFile(dir / "b.dcm", withTransferSyntax(readBytes(files[1]), c.uid));
        expectThrowWith<palp::FormatError>([&] { palp::volume::readStack({dir}, {}); },
                                           {(dir / "b.dcm").string() + ": expected", c.named});
        // Only such files: "found none" would hide them; the syntax is named instead.
        fs::remove(dir / "a.dcm");
        expectThrowWith<palp::FormatError>([&] { palp::volume::readStack({dir}, {}); },
                                           {(dir / "b.dcm").string() + ": expected", c.named});
    }
}

/// The pixels GDCM alone decodes from @p file (false when GDCM reports a failure).
bool gdcmDecodes(const fs::path& file, std::vector<char>& pixels) {
    gdcm::ImageReader reader;
    reader.SetFileName(file.c_str());
    if (!reader.Read()) return false;
    pixels.resize(reader.GetImage().GetBufferLength());
    return reader.GetImage().GetBuffer(pixels.data());
}

TEST(DicomSyntax, DamagedJpeg2000IsRefusedWhereGdcmDecodesIt) {
    PALP_REQUIRE_DATA(dir, "ct-ge-head-tilt");
    if (!palp::test::haveProgram("gdcmconv"))
        GTEST_SKIP() << "gdcmconv (libgdcm-tools) not installed";
    TempDir tmp;
    for (const char* n : {"10.dcm", "11.dcm"}) {
        const auto r = palp::test::runCommand("gdcmconv --j2k '" + (dir / n).string() + "' '" +
                                              (tmp / n).string() + "'");
        ASSERT_EQ(r.exitCode, 0) << r.output;
    }
    const SliceStack intact = palp::volume::readStack({tmp.path()}, {});
    ASSERT_EQ(intact.slices.size(), 2u);
    const SliceStack original = palp::volume::readStack({dir / "10.dcm", dir / "11.dcm"}, {});
    EXPECT_EQ(intact.slices[1].values, original.slices[1].values);

    const fs::path file = tmp / "11.dcm";
    const std::string bytes = readBytes(file);
    const std::size_t soc = bytes.find("\xFF\x4F\xFF\x51");
    const std::size_t eoc = bytes.rfind("\xFF\xD9");
    ASSERT_NE(soc, std::string::npos);
    ASSERT_NE(eoc, std::string::npos);
    std::vector<char> good;
    ASSERT_TRUE(gdcmDecodes(file, good));
    // One bit changed a quarter, half and three quarters into the codestream: inside
    // arithmetic-coded code-block data, where GDCM (OpenJPEG without the check) decodes wrong
    // pixels and says nothing.
    for (const double at : {0.25, 0.5, 0.75}) {
        std::string damaged = bytes;
        const auto pos = soc + static_cast<std::size_t>(at * static_cast<double>(eoc - soc));
        damaged[pos] = static_cast<char>(damaged[pos] ^ 0x10);
        palp::test::writeFile(file, damaged);
        std::vector<char> bad;
        ASSERT_TRUE(gdcmDecodes(file, bad)) << "GDCM refused it by itself at byte " << pos;
        EXPECT_NE(bad, good) << "the change at byte " << pos << " changed no pixel";
        expectThrowWith<palp::FormatError>(
            [&] { palp::volume::readStack({file}, {}); },
            {file.string() + ": expected intact JPEG 2000 pixel data",
             "1.2.840.10008.1.2.4.90 (JPEG 2000 Image Compression (Lossless Only))",
             "found a damaged code-block (OpenJPEG: PTERM check failure"});
    }
}

/// What @p fn writes to the process's stderr (libjpeg's warnings go there through fprintf).
std::string capturedStderr(const std::function<void()>& fn) {
    std::fflush(stderr);
    char path[] = "/tmp/palp_stderr_XXXXXX";
    const int fd = mkstemp(path);
    if (fd < 0) {
        fn();
        return {};
    }
    const int saved = dup(2);
    dup2(fd, 2);
    fn();
    std::fflush(stderr);
    dup2(saved, 2);
    close(saved);
    close(fd);
    const std::string text = readBytes(path);
    std::remove(path);
    return text;
}

/// Two 160x128 slices with texture (a smooth pattern plus deterministic noise, so that the
/// lossless JPEG stream is tens of KiB), written by palp's DICOM writer into @p dir.
void writeTexturedSeries(const fs::path& dir) {
    SliceStack stack;
    std::uint32_t seed = 12345;
    for (int k = 0; k < 2; ++k) {
        Slice s;
        s.cols = 160;
        s.rows = 128;
        s.colStep = Eigen::Vector3d(0.8e-3, 0, 0);
        s.rowStep = Eigen::Vector3d(0, 0.8e-3, 0);
        s.position = Eigen::Vector3d(0, 0, 2e-3 * k);
        s.source = "slice";
        for (int r = 0; r < s.rows; ++r) {
            for (int c = 0; c < s.cols; ++c) {
                seed = seed * 1664525u + 1013904223u;
                const double smooth = 400 * std::sin(0.07 * c + k) * std::cos(0.05 * r);
                s.values.push_back(static_cast<float>(std::lround(smooth) + (seed >> 24) % 40));
            }
        }
        stack.slices.push_back(s);
    }
    palp::volume::writeDicomSeries(stack, dir);
}

TEST(DicomSyntax, DamagedLosslessJpegIsRefusedWhereGdcmDecodesIt) {
    if (!palp::test::haveProgram("gdcmconv"))
        GTEST_SKIP() << "gdcmconv (libgdcm-tools) not installed";
    TempDir tmp;
    writeTexturedSeries(tmp / "plain");
    fs::create_directories(tmp / "jpeg");
    std::vector<fs::path> names;
    for (const auto& e : fs::directory_iterator(tmp / "plain"))
        names.push_back(e.path().filename());
    std::sort(names.begin(), names.end());
    ASSERT_EQ(names.size(), 2u);
    for (const auto& n : names) {
        // --jpeg: JPEG Lossless, Non-Hierarchical, First-Order Prediction (process 14, SV1).
        const auto r = palp::test::runCommand("gdcmconv --jpeg '" + (tmp / "plain" / n).string() +
                                              "' '" + (tmp / "jpeg" / n).string() + "'");
        ASSERT_EQ(r.exitCode, 0) << r.output;
    }
    const SliceStack plain = palp::volume::readStack({tmp / "plain"}, {});
    const SliceStack intact = palp::volume::readStack({tmp / "jpeg"}, {});
    ASSERT_EQ(intact.slices.size(), 2u);
    for (std::size_t k = 0; k < 2; ++k) EXPECT_EQ(intact.slices[k].values, plain.slices[k].values);

    const fs::path file = tmp / "jpeg" / names[1];
    const std::string bytes = readBytes(file);
    const std::size_t sos = bytes.find("\xFF\xDA");
    const std::size_t eoi = bytes.rfind("\xFF\xD9");
    ASSERT_NE(sos, std::string::npos);
    ASSERT_NE(eoi, std::string::npos);
    ASSERT_GT(eoi - sos, std::size_t{16384}) << "the stream should span several 4 KiB blocks";
    std::vector<char> good;
    ASSERT_TRUE(gdcmDecodes(file, good));
    const std::vector<std::string> refusal = {
        file.string() +
            ": expected intact lossless JPEG pixel data (transfer syntax "
            "1.2.840.10008.1.2.4.70 (",
        "), found ", " in frame 1 of 1"};
    // One byte inverted at 41 places spread over the entropy-coded data. Where GDCM decodes the
    // file and its libjpeg says "Corrupt JPEG data" on stderr (the case: other pixels,
    // exit 0), palp must refuse it; where libjpeg says nothing, palp finds most changes too.
    int warnedOnly = 0, refused = 0, tried = 0;
    for (int k = 0; k < 41; ++k) {
        std::string damaged = bytes;
        const std::size_t pos = sos + 16 + (eoi - sos - 20) * static_cast<std::size_t>(k) / 41;
        damaged[pos] = static_cast<char>(~damaged[pos]);
        palp::test::writeFile(file, damaged);
        std::vector<char> bad;
        bool decoded = false;
        const std::string stderrText = capturedStderr([&] { decoded = gdcmDecodes(file, bad); });
        bool threw = false;
        try {
            palp::volume::readStack({file}, {});
        } catch (const palp::FormatError& e) {
            threw = true;
            // Where GDCM fails the stream itself (two libjpeg warnings) palp's walk names the
            // damage too; the message is GDCM's failure only if the walk finds nothing.
            const std::string msg = e.what();
            if (decoded || msg.find("cannot be decoded") == std::string::npos) {
                for (const auto& part : refusal)
                    EXPECT_NE(msg.find(part), std::string::npos) << msg;
            }
        }
        ++tried;
        refused += threw ? 1 : 0;
        if (decoded && stderrText.find("Corrupt JPEG data") != std::string::npos) {
            ++warnedOnly;
            EXPECT_NE(bad, good) << "the change at byte " << pos << " changed no pixel";
            EXPECT_TRUE(threw) << "libjpeg warned (" << stderrText << ") at byte " << pos
                               << ", palp read the file";
            if (warnedOnly == 1) {
                // load() (as palp convert) refuses it too, whichever slice it decodes first.
                expectThrowWith<palp::FormatError>([&] { palp::volume::load({tmp / "jpeg"}, {}); },
                                                   refusal);
            }
        }
    }
    EXPECT_GE(warnedOnly, 3) << "too few changes that GDCM decodes with a libjpeg warning";
    EXPECT_GE(refused, warnedOnly);
    std::printf(
        "lossless JPEG: %d of %d single-byte inversions refused; GDCM decoded %d of them "
        "with only a libjpeg warning\n",
        refused, tried, warnedOnly);
    // A byte changed every 4 KiB of the file (libjpeg: "bad Huffman code", GDCM decodes).
    std::string damaged = bytes;
    for (std::size_t pos = sos + 4096; pos < eoi; pos += 4096)
        damaged[pos] = static_cast<char>(damaged[pos] ^ 0x5A);
    palp::test::writeFile(file, damaged);
    expectThrowWith<palp::FormatError>([&] { palp::volume::readStack({file}, {}); }, refusal);
    // The intact file reads again.
    palp::test::writeFile(file, bytes);
    EXPECT_EQ(palp::volume::readStack({file}, {}).slices[0].values, plain.slices[1].values);
}

TEST(DicomSyntax, ZeroedTailOfEncapsulatedPixelDataIsNamedAsSuch) {
    // A copy that stopped part way and was padded with zeros to its size: the encapsulated pixel
    // data's items give way to zeros. Reported before issue 37 as "expected a complete DICOM
    // header, found an invalid value representation".
    if (!palp::test::haveProgram("gdcmconv"))
        GTEST_SKIP() << "gdcmconv (libgdcm-tools) not installed";
    TempDir tmp;
    writeTexturedSeries(tmp / "plain");
    std::vector<fs::path> names;
    for (const auto& e : fs::directory_iterator(tmp / "plain")) names.push_back(e.path());
    std::sort(names.begin(), names.end());
    const fs::path file = tmp / "z.dcm";
    const auto r = palp::test::runCommand("gdcmconv --jpeg '" + names[0].string() + "' '" +
                                          file.string() + "'");
    ASSERT_EQ(r.exitCode, 0) << r.output;
    std::string bytes = readBytes(file);
    const std::size_t sos = bytes.find("\xFF\xDA");
    ASSERT_NE(sos, std::string::npos);
    const std::size_t from = sos + (bytes.size() - sos) / 2;
    std::fill(bytes.begin() + static_cast<std::ptrdiff_t>(from), bytes.end(), '\0');
    palp::test::writeFile(file, bytes);
    try {
        palp::volume::readStack({file}, {});
        ADD_FAILURE() << "expected a refusal";
    } catch (const palp::FormatError& e) {
        const std::string msg = e.what();
        EXPECT_NE(msg.find(file.string() +
                           ": expected complete pixel data of 160x128x16 bits, found zero bytes "
                           "from here to the end of the file where pixel data fragments were "
                           "expected at byte "),
                  std::string::npos)
            << msg;
        EXPECT_NE(msg.find("(the end of the file is zeroed: an incomplete copy)"),
                  std::string::npos)
            << msg;
        EXPECT_EQ(msg.find("DICOM header"), std::string::npos) << msg;
    }
}

/// A copy of @p from with Gantry/Detector Tilt (0018,1120) set to @p value.
void writeWithTilt(const fs::path& from, const fs::path& to, const std::string& value) {
    gdcm::Reader reader;
    reader.SetFileName(from.c_str());
    ASSERT_TRUE(reader.Read());
    gdcm::DataElement de(gdcm::Tag(0x0018, 0x1120));
    de.SetVR(gdcm::VR::DS);
    de.SetByteValue(value.data(), static_cast<std::uint32_t>(value.size()));
    reader.GetFile().GetDataSet().Replace(de);
    gdcm::Writer writer;
    writer.SetFile(reader.GetFile());
    writer.SetFileName(to.c_str());
    ASSERT_TRUE(writer.Write());
}

TEST(DicomSyntax, GantryTiltKeepsTheSignOfTheTag) {
    PALP_REQUIRE_DATA(dir, "ct-ge-head-tilt");
    // The scan's tag says +18.5; its orientation (column cosine (0, 0.9483237, -0.3173047)) gives
    // acos(0.9483237) = 18.50 degrees between the slice normal and the stacking direction.
    palp::volume::LoadOptions opt;
    opt.resample.voxelSize = 4e-3;  // coarse: the tilt comes from the geometry, not the grid
    const std::vector<std::string> names = {"10.dcm", "11.dcm", "12.dcm"};
    std::vector<fs::path> originals;
    for (const auto& n : names) originals.push_back(dir / n);
    const palp::volume::Volume asGiven = palp::volume::load(originals, opt);
    EXPECT_NEAR(asGiven.info.gantryTiltDeg, 18.5, 0.01);

    TempDir tmp;
    std::vector<fs::path> negated;
    for (const auto& n : names) {
        writeWithTilt(dir / n, tmp / n, "-18.5 ");
        negated.push_back(tmp / n);
    }
    const palp::volume::Volume vol = palp::volume::load(negated, opt);
    EXPECT_NEAR(vol.info.gantryTiltDeg, -18.5, 0.01);
    // The metadata written with the grid says the same after a save and a load.
    palp::volume::save(vol, tmp / "tilt.vdb");
    EXPECT_NEAR(palp::volume::loadVdb(tmp / "tilt.vdb").info.gantryTiltDeg, -18.5, 0.01);
    // The geometry is the tag's business only for the sign: the grids are the same.
    EXPECT_EQ(vol.grid->activeVoxelCount(), asGiven.grid->activeVoxelCount());
}

}  // namespace
