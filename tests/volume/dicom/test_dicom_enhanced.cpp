// Enhanced multi-frame DICOM split over several files (Siemens XA style): a known 4D volume
// (6 positions x 4 time points, oblique, per-frame rescale) written at test time as one enhanced
// MR file per time point, as files that each hold some positions at every time point, and as
// one file per position; every time point reads back exactly (values and world positions), is
// counted by scanDicom as `palp info` shows it, and agrees with dcm2niix where it converts the
// same files. Bad series are refused naming the file and frame.
#include <gdcmTrace.h>
#include <gdcmWriter.h>
#include <gtest/gtest.h>
#include <nifti2_io.h>

#include <Eigen/Geometry>
#include <cmath>
#include <cstdint>
#include <functional>
#include <memory>
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
using palp::volume::SliceStack;

/// The known volume: 5 columns x 4 rows x 6 positions x 4 time points, 1.5 mm between columns,
/// 2.0 mm between rows, 2.5 mm between slices, rotated 0.4 rad about (2, -1, 1).
struct Known {
    static constexpr int kCols = 5, kRows = 4, kPositions = 6, kTimes = 4;
    static constexpr double kColSpacing = 1.5, kRowSpacing = 2.0, kSliceSpacing = 2.5;
    Eigen::Matrix3d rotation =
        Eigen::AngleAxisd(0.4, Eigen::Vector3d(2, -1, 1).normalized()).toRotationMatrix();
    Eigen::Vector3d firstMm{-20, 35.5, -12};
    Eigen::Vector3d rowCosine() const { return rotation.col(0); }
    Eigen::Vector3d columnCosine() const { return rotation.col(1); }
    Eigen::Vector3d normal() const { return rotation.col(2); }
    Eigen::Vector3d positionMm(int k) const { return firstMm + k * kSliceSpacing * normal(); }
    static std::int16_t stored(int c, int r, int k, int t) {
        return static_cast<std::int16_t>(1000 * t + 100 * k + 10 * r + c - 200);
    }
    // Each position has its own rescale (Pixel Value Transformation per frame).
    static double slope(int k) { return 1 + k % 2; }
    static double intercept(int k) { return -5.0 * k; }
    static float value(int c, int r, int k, int t) {
        return static_cast<float>(slope(k) * stored(c, r, k, t) + intercept(k));
    }
};

/// One frame to write: known position k at time point t, with changes for bad-input cases.
struct Frame {
    int k = 0, t = 0;
    int positionOf = -1;  // >= 0: the Plane Position of that position instead (a duplicate)
    Eigen::Matrix3d rotation = Known().rotation;
};

struct FileOptions {
    std::string seriesUid = "1.2.826.0.1.3680043.2.1125.9.1";
    int instance = 1;           // writePerTimePoint: -1 numbers the files backwards in time
    bool temporalIndex = true;  // Temporal Position Index and Dimension Index Values
    bool frameTime = true;      // Frame Acquisition DateTime
    int rows = Known::kRows;
    // false: one rescale (slope 2, intercept -10) for every frame, for dcm2niix, which applies
    // one frame's rescale to the whole file.
    bool perFrameRescale = true;
    bool constantTemporalIndex = false;  // index 1 in every file
    int temporalPositions = 0;           // > 0: Number of Temporal Positions (0020,0105)
};

/// @p prefix, @p n and @p suffix (appended in place: GCC 12 warns falsely on "x" + std::string).
std::string named(const char* prefix, int n, const char* suffix) {
    std::string s = prefix;
    s += std::to_string(n);
    s += suffix;
    return s;
}

std::string num(double v) {
    char buf[32];
    std::snprintf(buf, sizeof buf, "%.10g", v);
    return buf;
}

void put(gdcm::DataSet& ds, std::uint16_t g, std::uint16_t e, gdcm::VR vr, std::string v) {
    if (v.size() % 2) v.push_back(vr == gdcm::VR::UI ? '\0' : ' ');
    gdcm::DataElement de(gdcm::Tag(g, e));
    de.SetVR(vr);
    de.SetByteValue(v.data(), static_cast<std::uint32_t>(v.size()));
    ds.Replace(de);
}

void putBinary(gdcm::DataSet& ds, std::uint16_t g, std::uint16_t e, gdcm::VR vr, const void* data,
               std::size_t bytes) {
    gdcm::DataElement de(gdcm::Tag(g, e));
    de.SetVR(vr);
    de.SetByteValue(static_cast<const char*>(data), static_cast<std::uint32_t>(bytes));
    ds.Replace(de);
}

void putUs(gdcm::DataSet& ds, std::uint16_t g, std::uint16_t e, std::uint16_t v) {
    putBinary(ds, g, e, gdcm::VR::US, &v, 2);
}

void putUl(gdcm::DataSet& ds, std::uint16_t g, std::uint16_t e, std::vector<std::uint32_t> v) {
    putBinary(ds, g, e, gdcm::VR::UL, v.data(), v.size() * 4);
}

/// Puts a sequence of one item, filled by @p fill, into @p ds.
void putItem(gdcm::DataSet& ds, std::uint16_t g, std::uint16_t e,
             const std::function<void(gdcm::DataSet&)>& fill) {
    gdcm::SmartPointer<gdcm::SequenceOfItems> sq = new gdcm::SequenceOfItems;
    sq->SetLengthToUndefined();
    gdcm::Item item;
    item.SetVLToUndefined();
    fill(item.GetNestedDataSet());
    sq->AddItem(item);
    gdcm::DataElement de(gdcm::Tag(g, e));
    de.SetVR(gdcm::VR::SQ);
    de.SetValue(*sq);
    de.SetVLToUndefined();
    ds.Replace(de);
}

std::string orientationText(const Eigen::Matrix3d& rot) {
    return num(rot(0, 0)) + "\\" + num(rot(1, 0)) + "\\" + num(rot(2, 0)) + "\\" + num(rot(0, 1)) +
           "\\" + num(rot(1, 1)) + "\\" + num(rot(2, 1));
}

/// Writes @p frames as one enhanced MR image storage file (explicit VR little endian, int16),
/// orientation and spacing in the shared functional groups unless a frame has its own.
void writeEnhanced(const fs::path& file, const std::vector<Frame>& frames,
                   const FileOptions& o = {}) {
    const Known known;
    fs::create_directories(file.parent_path());
    gdcm::Trace::WarningOff();
    gdcm::Writer writer;
    gdcm::File& f = writer.GetFile();
    f.GetHeader().SetDataSetTransferSyntax(gdcm::TransferSyntax::ExplicitVRLittleEndian);
    gdcm::DataSet& ds = f.GetDataSet();
    put(ds, 0x0008, 0x0008, gdcm::VR::CS, "ORIGINAL\\PRIMARY\\M\\NONE");
    put(ds, 0x0008, 0x0016, gdcm::VR::UI, "1.2.840.10008.5.1.4.1.1.4.1");  // Enhanced MR
    put(ds, 0x0008, 0x0018, gdcm::VR::UI, o.seriesUid + ".100." + std::to_string(o.instance));
    put(ds, 0x0008, 0x0020, gdcm::VR::DA, "20250301");
    put(ds, 0x0008, 0x0023, gdcm::VR::DA, "20250301");
    put(ds, 0x0008, 0x0033, gdcm::VR::TM, named("1200", 10 + o.instance, ".000000"));
    put(ds, 0x0008, 0x0060, gdcm::VR::CS, "MR");
    put(ds, 0x0008, 0x0070, gdcm::VR::LO, "SIEMENS");
    put(ds, 0x0008, 0x103e, gdcm::VR::LO, "xa enhanced bold");
    put(ds, 0x0010, 0x0010, gdcm::VR::PN, "PALP^TEST");
    put(ds, 0x0020, 0x000d, gdcm::VR::UI, o.seriesUid + ".1");
    put(ds, 0x0020, 0x000e, gdcm::VR::UI, o.seriesUid);
    put(ds, 0x0020, 0x0011, gdcm::VR::IS, "7");
    put(ds, 0x0020, 0x0013, gdcm::VR::IS, std::to_string(o.instance));
    put(ds, 0x0020, 0x0052, gdcm::VR::UI, o.seriesUid + ".2");
    if (o.temporalPositions > 0)
        put(ds, 0x0020, 0x0105, gdcm::VR::IS, std::to_string(o.temporalPositions));
    putUs(ds, 0x0028, 0x0002, 1);
    put(ds, 0x0028, 0x0004, gdcm::VR::CS, "MONOCHROME2");
    put(ds, 0x0028, 0x0008, gdcm::VR::IS, std::to_string(frames.size()));
    putUs(ds, 0x0028, 0x0010, static_cast<std::uint16_t>(o.rows));
    putUs(ds, 0x0028, 0x0011, Known::kCols);
    putUs(ds, 0x0028, 0x0100, 16);
    putUs(ds, 0x0028, 0x0101, 16);
    putUs(ds, 0x0028, 0x0102, 15);
    putUs(ds, 0x0028, 0x0103, 1);
    putItem(ds, 0x5200, 0x9229, [&](gdcm::DataSet& shared) {
        putItem(shared, 0x0028, 0x9110, [&](gdcm::DataSet& m) {
            put(m, 0x0028, 0x0030, gdcm::VR::DS,
                num(Known::kRowSpacing) + "\\" + num(Known::kColSpacing));
            put(m, 0x0018, 0x0050, gdcm::VR::DS, num(Known::kSliceSpacing));
            put(m, 0x0018, 0x0088, gdcm::VR::DS, num(Known::kSliceSpacing));
        });
        putItem(shared, 0x0020, 0x9116, [&](gdcm::DataSet& p) {
            put(p, 0x0020, 0x0037, gdcm::VR::DS, orientationText(known.rotation));
        });
    });
    gdcm::SmartPointer<gdcm::SequenceOfItems> perFrame = new gdcm::SequenceOfItems;
    perFrame->SetLengthToUndefined();
    std::vector<std::int16_t> pixels;
    for (const Frame& fr : frames) {
        gdcm::Item item;
        item.SetVLToUndefined();
        gdcm::DataSet& g = item.GetNestedDataSet();
        const Eigen::Vector3d p = known.positionMm(fr.positionOf >= 0 ? fr.positionOf : fr.k);
        putItem(g, 0x0020, 0x9113, [&](gdcm::DataSet& s) {
            put(s, 0x0020, 0x0032, gdcm::VR::DS,
                num(p.x()) + "\\" + num(p.y()) + "\\" + num(p.z()));
        });
        if (!fr.rotation.isApprox(known.rotation)) {
            putItem(g, 0x0020, 0x9116, [&](gdcm::DataSet& s) {
                put(s, 0x0020, 0x0037, gdcm::VR::DS, orientationText(fr.rotation));
            });
        }
        putItem(g, 0x0028, 0x9145, [&](gdcm::DataSet& s) {
            put(s, 0x0028, 0x1052, gdcm::VR::DS,
                num(o.perFrameRescale ? Known::intercept(fr.k) : -10.0));
            put(s, 0x0028, 0x1053, gdcm::VR::DS, num(o.perFrameRescale ? Known::slope(fr.k) : 2.0));
            put(s, 0x0028, 0x1054, gdcm::VR::LO, "US");
        });
        putItem(g, 0x0020, 0x9111, [&](gdcm::DataSet& s) {
            if (o.temporalIndex) {
                const auto index =
                    static_cast<std::uint32_t>(o.constantTemporalIndex ? 1 : fr.t + 1);
                putUl(s, 0x0020, 0x9128, {index});
                putUl(s, 0x0020, 0x9157, {index, static_cast<std::uint32_t>(fr.k + 1)});
            }
            if (o.frameTime) {
                // Slices 0.1 s apart, time points 2 s apart (one TR).
                const double seconds = 10 + 2.0 * fr.t + 0.1 * fr.k;
                char dt[64];
                std::snprintf(dt, sizeof dt, "202503011200%06.3f", seconds);
                put(s, 0x0018, 0x9074, gdcm::VR::DT, dt);
            }
        });
        perFrame->AddItem(item);
        for (int r = 0; r < o.rows; ++r)
            for (int c = 0; c < Known::kCols; ++c)
                pixels.push_back(Known::stored(c, r, fr.k, fr.t));
    }
    gdcm::DataElement pf(gdcm::Tag(0x5200, 0x9230));
    pf.SetVR(gdcm::VR::SQ);
    pf.SetValue(*perFrame);
    pf.SetVLToUndefined();
    ds.Replace(pf);
    putBinary(ds, 0x7fe0, 0x0010, gdcm::VR::OW, pixels.data(), pixels.size() * 2);
    writer.SetFileName(file.c_str());
    ASSERT_TRUE(writer.Write()) << file;
}

/// The positions of a time point in an order other than the slices' (as interleaved slices).
std::vector<int> interleaved() { return {0, 2, 4, 1, 3, 5}; }

/// One file per time point (Siemens XA): t1.dcm ... t4.dcm, slices interleaved in each.
void writePerTimePoint(const fs::path& dir, const FileOptions& base = {}) {
    fs::create_directories(dir);
    for (int t = 0; t < Known::kTimes; ++t) {
        std::vector<Frame> frames;
        for (int k : interleaved()) frames.push_back({k, t});
        FileOptions o = base;
        o.instance = base.instance < 0 ? Known::kTimes - t : t + 1;
        writeEnhanced(dir / named("t", t + 1, ".dcm"), frames, o);
    }
}

void expectKnownTimePoint(const SliceStack& st, int t) {
    const Known known;
    ASSERT_EQ(st.slices.size(), static_cast<std::size_t>(Known::kPositions));
    EXPECT_EQ(st.info.originalDims, (std::array<std::int64_t, 3>{5, 4, 6}));
    EXPECT_EQ(st.info.timePointCount, Known::kTimes);
    EXPECT_EQ(st.info.timePoint, t);
    for (int k = 0; k < Known::kPositions; ++k) {
        const auto& s = st.slices[static_cast<std::size_t>(k)];
        ASSERT_EQ(s.cols, Known::kCols);
        ASSERT_EQ(s.rows, Known::kRows);
        for (int r = 0; r < Known::kRows; ++r) {
            for (int c = 0; c < Known::kCols; ++c) {
                const Eigen::Vector3d p = (s.position + c * s.colStep + r * s.rowStep) * 1e3;
                const Eigen::Vector3d expected = known.positionMm(k) +
                                                 c * Known::kColSpacing * known.rowCosine() +
                                                 r * Known::kRowSpacing * known.columnCosine();
                EXPECT_LT((p - expected).norm(), 1e-6) << "t " << t << " slice " << k;
                EXPECT_EQ(s.values[static_cast<std::size_t>(r * Known::kCols + c)],
                          Known::value(c, r, k, t))
                    << "t " << t << " slice " << k << " pixel " << c << "," << r;
            }
        }
    }
}

/// scanDicom's counts (what `palp info` prints) and every time point read exactly.
void expectKnownSeries(const fs::path& dir, int files) {
    const auto series = palp::volume::scanDicom({dir});
    ASSERT_EQ(series.size(), 1u);
    EXPECT_EQ(series[0].imageCount, files);
    EXPECT_EQ(series[0].frameCount, Known::kPositions * Known::kTimes);
    EXPECT_EQ(series[0].positionCount, Known::kPositions);
    EXPECT_EQ(series[0].timePointCount, Known::kTimes);
    EXPECT_EQ(series[0].problem, "");
    expectThrowWith<palp::ValueError>([&] { palp::volume::readStack({dir}, {}); },
                                      {"one of the 4 time points (0-3)"});
    for (int t = 0; t < Known::kTimes; ++t) {
        palp::volume::LoadOptions opt;
        opt.timePoint = t;
        expectKnownTimePoint(palp::volume::readStack({dir}, opt), t);
    }
}

TEST(DicomEnhanced, OneFilePerTimePointReadsEveryTimePointExactly) {
    TempDir tmp;
    writePerTimePoint(tmp / "a");
    expectKnownSeries(tmp / "a", 4);
    // Without frame-level time keys the files' Instance Number and Content Time order them.
    FileOptions plain;
    plain.temporalIndex = false;
    plain.frameTime = false;
    writePerTimePoint(tmp / "b", plain);
    expectKnownSeries(tmp / "b", 4);
    // Temporal Position Index 1 and Dimension Index Values 1\k in every file (as Canon and some
    // Siemens XA files have them): no information, so the files' own keys order them.
    FileOptions constantIndex = plain;
    constantIndex.constantTemporalIndex = true;
    constantIndex.temporalIndex = true;
    writePerTimePoint(tmp / "i", constantIndex);
    expectKnownSeries(tmp / "i", 4);
    // Frame Acquisition DateTime alone orders them, against the files' own keys (Instance Number
    // and Content Time falling as time goes on; writePerTimePoint reverses them for instance -1).
    FileOptions frameTimeOnly;
    frameTimeOnly.temporalIndex = false;
    frameTimeOnly.instance = -1;
    writePerTimePoint(tmp / "c", frameTimeOnly);
    expectKnownSeries(tmp / "c", 4);
}

TEST(DicomEnhanced, VolumeSplitByPositionReadsEveryTimePointExactly) {
    TempDir tmp;
    // Two files of three positions each, every time point in each (time-major frame order).
    for (int half = 0; half < 2; ++half) {
        std::vector<Frame> frames;
        for (int t = 0; t < Known::kTimes; ++t)
            for (int k = 3 * half; k < 3 * half + 3; ++k) frames.push_back({k, t});
        FileOptions o;
        o.instance = half + 1;
        writeEnhanced(tmp / "halves" / named("part", half + 1, ".dcm"), frames, o);
    }
    expectKnownSeries(tmp / "halves", 2);
    // One file per position, time points in frame order only (no frame-level time keys).
    FileOptions o;
    o.temporalIndex = false;
    o.frameTime = false;
    for (int k = 0; k < Known::kPositions; ++k) {
        std::vector<Frame> frames;
        for (int t = 0; t < Known::kTimes; ++t) frames.push_back({k, t});
        o.instance = Known::kPositions - k;  // file order is not slice order
        writeEnhanced(tmp / "single" / named("p", k, ".dcm"), frames, o);
    }
    expectKnownSeries(tmp / "single", Known::kPositions);
}

TEST(DicomEnhanced, PalpInfoCountsFramesAndConvertTakesVolume) {
    TempDir tmp;
    writePerTimePoint(tmp / "s");
    const auto r = palp::test::runCommand("'" + palp::test::palpTool().string() +
                                          "' info --json '" + (tmp / "s").string() + "'");
    ASSERT_EQ(r.exitCode, 0) << r.output;
    for (const std::string field :
         {"\"images\": 4", "\"frames\": 24", "\"positions\": 6", "\"time_points\": 4"}) {
        EXPECT_NE(r.output.find(field), std::string::npos) << field << "\n" << r.output;
    }
    // palp convert asks for the time point, then converts the one chosen.
    const std::string convert = "'" + palp::test::palpTool().string() + "' convert '" +
                                (tmp / "s").string() + "' -o '" + (tmp / "out.vdb").string() + "'";
    const auto refused = palp::test::runCommand(convert);
    EXPECT_NE(refused.exitCode, 0);
    EXPECT_NE(refused.output.find("one of the 4 time points (0-3)"), std::string::npos)
        << refused.output;
    EXPECT_NE(refused.output.find("--volume N"), std::string::npos) << refused.output;
    const auto converted = palp::test::runCommand(convert + " --volume 2");
    ASSERT_EQ(converted.exitCode, 0) << converted.output;
    const palp::volume::Volume vol = palp::volume::loadVdb(tmp / "out.vdb");
    EXPECT_EQ(vol.info.timePoint, 2);
    EXPECT_EQ(vol.info.timePointCount, 4);
    EXPECT_EQ(vol.info.originalDims, (std::array<std::int64_t, 3>{5, 4, 6}));
}

TEST(DicomEnhanced, FrameWithOtherOrientationIsRefusedByFileAndFrame) {
    TempDir tmp;
    writePerTimePoint(tmp / "s");
    std::vector<Frame> frames;
    for (int k : interleaved()) frames.push_back({k, 2});
    frames[4].rotation = Eigen::AngleAxisd(0.05, Eigen::Vector3d::UnitZ()) * Known().rotation;
    FileOptions o;
    o.instance = 3;
    writeEnhanced(tmp / "s" / "t3.dcm", frames, o);
    palp::volume::LoadOptions opt;
    opt.timePoint = 0;  // another time point's frame: the series is refused as a whole
    expectThrowWith<palp::FormatError>(
        [&] { palp::volume::readStack({tmp / "s"}, opt); },
        {(tmp / "s" / "t3.dcm").string() + " (frame 5): expected the orientation of", "(frame 1)",
         "found row"});
}

TEST(DicomEnhanced, FileOfOtherSizeIsRefusedByFileAndFrame) {
    TempDir tmp;
    writePerTimePoint(tmp / "s");
    std::vector<Frame> frames;
    for (int k : interleaved()) frames.push_back({k, 3});
    FileOptions o;
    o.instance = 4;
    o.rows = 3;
    writeEnhanced(tmp / "s" / "t4.dcm", frames, o);
    expectThrowWith<palp::FormatError>(
        [&] { palp::volume::readStack({tmp / "s"}, {}); },
        {(tmp / "s" / "t4.dcm").string() + " (frame 1): expected 5x4 pixels", "found 5x3"});
}

TEST(DicomEnhanced, MissingTimePointIsRefused) {
    TempDir tmp;
    writePerTimePoint(tmp / "s");
    fs::remove(tmp / "s" / "t3.dcm");
    expectThrowWith<palp::FormatError>(
        [&] { palp::volume::readStack({tmp / "s"}, {}); },
        {"expected Temporal Position Index (0020,9128) values 1 to 3", "found 1, 2, 4",
         "(index 3 missing: the series lacks time points)"});
    // The last time point missing: only Number of Temporal Positions tells.
    FileOptions declared;
    declared.temporalPositions = 5;
    writePerTimePoint(tmp / "d", declared);
    expectThrowWith<palp::FormatError>(
        [&] { palp::volume::readStack({tmp / "d"}, {}); },
        {"expected 5 time points as Number of Temporal Positions (0020,0105) of",
         "t1.dcm says, found 4"});
    // Split by position: a file that lacks a time point leaves its positions short.
    for (int half = 0; half < 2; ++half) {
        std::vector<Frame> frames;
        for (int t = 0; t < Known::kTimes - half; ++t)
            for (int k = 3 * half; k < 3 * half + 3; ++k) frames.push_back({k, t});
        FileOptions o;
        o.instance = half + 1;
        writeEnhanced(tmp / "halves" / named("part", half + 1, ".dcm"), frames, o);
    }
    expectThrowWith<palp::ValueError>(
        [&] { palp::volume::readStack({tmp / "halves"}, {}); },
        {"expected the same number of images at every slice position (4 at 3 of 6 positions), "
         "found 3",
         (tmp / "halves" / "part2.dcm").string() + " (frame"});
}

TEST(DicomEnhanced, DuplicatedPositionsAreRefused) {
    TempDir tmp;
    // A frame that repeats another's position in the same time point.
    writePerTimePoint(tmp / "s");
    std::vector<Frame> frames;
    for (int k : interleaved()) frames.push_back({k, 1});
    frames[5].positionOf = frames[4].k;  // frame 6 (position 5) at frame 5's position (3)
    FileOptions o;
    o.instance = 2;
    writeEnhanced(tmp / "s" / "t2.dcm", frames, o);
    expectThrowWith<palp::FormatError>(
        [&] { palp::volume::readStack({tmp / "s"}, {}); },
        {"expected one frame per Temporal Position Index (0020,9128) at each slice position",
         (tmp / "s" / "t2.dcm").string() + " (frame 5) and", "(frame 6) both with index 2",
         "mm along the normal"});
    // A copied file: every frame twice with the same time keys.
    writePerTimePoint(tmp / "c");
    fs::copy_file(tmp / "c" / "t2.dcm", tmp / "c" / "t2 copy.dcm");
    expectThrowWith<palp::FormatError>(
        [&] { palp::volume::readStack({tmp / "c"}, {}); },
        {"expected one frame per time point at each slice position",
         (tmp / "c" / "t2 copy.dcm").string(), "a duplicated file or frame"});
    // scanDicom (palp info) says why the series cannot be converted.
    const auto series = palp::volume::scanDicom({tmp / "c"});
    ASSERT_EQ(series.size(), 1u);
    EXPECT_EQ(series[0].frameCount, 30);
    EXPECT_NE(series[0].problem.find("a duplicated file or frame"), std::string::npos)
        << series[0].problem;
    EXPECT_TRUE(palp::volume::scanDicom({tmp / "s"})[0].problem.find("index 2") !=
                std::string::npos);
}

/// dcm2niix as an oracle: it writes each enhanced file (time point) as its own volume; every
/// palp pixel centre of time point t must be a voxel centre of dcm2niix's volume of file t
/// holding the same value. One rescale for all frames: dcm2niix (v1.0.20220720) applies the
/// rescale of one frame to the whole file, where palp applies each frame's own.
TEST(DicomEnhanced, AgreesWithDcm2niixOnEveryVoxelCentreAndValue) {
    if (!palp::test::haveProgram("dcm2niix")) GTEST_SKIP() << "dcm2niix not installed";
    TempDir tmp;
    FileOptions o;
    o.perFrameRescale = false;
    writePerTimePoint(tmp / "dicom", o);
    fs::create_directories(tmp / "nifti");
    const auto r =
        palp::test::runCommand("dcm2niix -z n -b n -f enhanced_%r -o '" + (tmp / "nifti").string() +
                               "' '" + (tmp / "dicom").string() + "'");
    ASSERT_EQ(r.exitCode, 0) << r.output;
    for (int t = 0; t < Known::kTimes; ++t) {
        SCOPED_TRACE("time point " + std::to_string(t));
        const fs::path nii = tmp / "nifti" / named("enhanced_", t + 1, ".nii");
        ASSERT_TRUE(fs::exists(nii)) << r.output;
        const std::unique_ptr<nifti_image, void (*)(nifti_image*)> image(
            nifti_image_read(nii.c_str(), 1), nifti_image_free);
        const nifti_image* nim = image.get();
        ASSERT_NE(nim, nullptr);
        ASSERT_EQ(nim->nx * nim->ny * nim->nz, Known::kCols * Known::kRows * Known::kPositions);
        const nifti_dmat44 toIndex =
            nifti_dmat44_inverse(nim->sform_code > 0 ? nim->sto_xyz : nim->qto_xyz);
        const double scl = nim->scl_slope != 0 ? nim->scl_slope : 1.0;
        palp::volume::LoadOptions opt;
        opt.timePoint = t;
        const SliceStack st = palp::volume::readStack({tmp / "dicom"}, opt);
        int matched = 0;
        for (const auto& s : st.slices) {
            for (int row = 0; row < s.rows; ++row) {
                for (int col = 0; col < s.cols; ++col) {
                    const Eigen::Vector3d lps =
                        (s.position + col * s.colStep + row * s.rowStep) * 1e3;
                    const double ras[3] = {-lps.x(), -lps.y(), lps.z()};
                    double idx[3];
                    for (int a = 0; a < 3; ++a) {
                        idx[a] = toIndex.m[a][0] * ras[0] + toIndex.m[a][1] * ras[1] +
                                 toIndex.m[a][2] * ras[2] + toIndex.m[a][3];
                    }
                    const auto i = static_cast<std::int64_t>(std::round(idx[0]));
                    const auto j = static_cast<std::int64_t>(std::round(idx[1]));
                    const auto k = static_cast<std::int64_t>(std::round(idx[2]));
                    // dcm2niix's sform is stored as float.
                    EXPECT_LT(std::abs(idx[0] - static_cast<double>(i)) +
                                  std::abs(idx[1] - static_cast<double>(j)) +
                                  std::abs(idx[2] - static_cast<double>(k)),
                              1e-3);
                    ASSERT_TRUE(i >= 0 && i < nim->nx && j >= 0 && j < nim->ny && k >= 0 &&
                                k < nim->nz);
                    const auto at = static_cast<std::size_t>((k * nim->ny + j) * nim->nx + i);
                    double theirs = 0;
                    if (nim->datatype == DT_INT16) {
                        theirs = static_cast<const std::int16_t*>(nim->data)[at];
                    } else if (nim->datatype == DT_FLOAT32) {
                        theirs = static_cast<const float*>(nim->data)[at];
                    } else {
                        FAIL() << "dcm2niix datatype " << nim->datatype;
                    }
                    EXPECT_EQ(s.values[static_cast<std::size_t>(row * s.cols + col)],
                              static_cast<float>(theirs * scl + nim->scl_inter))
                        << s.source << " pixel " << col << "," << row;
                    ++matched;
                }
            }
        }
        EXPECT_EQ(matched, Known::kCols * Known::kRows * Known::kPositions);
    }
}

}  // namespace
