// Siemens MOSAIC: a synthetic mosaic made at test time from a known volume (oblique, non-square
// tiles, a 3x3 grid holding 7 slices, two time points, the CSA header's SliceNormalVector either
// way round) reads back exactly, agrees with dcm2niix on every voxel centre and value, and is
// counted by scanDicom as `palp info` shows it.
#include <gdcmAttribute.h>
#include <gdcmReader.h>
#include <gdcmWriter.h>
#include <gtest/gtest.h>
#include <nifti2_io.h>

#include <Eigen/Geometry>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <memory>
#include <string>
#include <vector>

#include "dicom_test_writer.h"
#include "palp/base/error.h"
#include "palp/volume/dicom.h"
#include "palp/volume/load.h"
#include "test_support.h"

namespace {

namespace fs = std::filesystem;
using palp::test::expectThrowWith;
using palp::test::TempDir;
using palp::volume::SliceStack;

/// The known volume: 6 columns x 5 rows x 7 slices, 2.0 mm between columns, 2.5 mm between
/// rows, 3.3 mm between slices, rotated 0.3 rad about (1, 2, 3).
struct Known {
    static constexpr int kCols = 6, kRows = 5, kSlices = 7, kGrid = 3;
    static constexpr double kColSpacing = 2.0, kRowSpacing = 2.5, kSliceSpacing = 3.3;
    Eigen::Matrix3d rotation =
        Eigen::AngleAxisd(0.3, Eigen::Vector3d(1, 2, 3).normalized()).toRotationMatrix();
    Eigen::Vector3d firstMm{-40, 12.5, 30};  // corner pixel centre of slice 0
    Eigen::Vector3d rowCosine() const { return rotation.col(0); }
    Eigen::Vector3d columnCosine() const { return rotation.col(1); }
    Eigen::Vector3d normal() const { return rotation.col(2); }
    static std::int16_t value(int c, int r, int k, int t) {
        return static_cast<std::int16_t>(1000 * t + 100 * k + 10 * r + c - 300);
    }
    /// World position (mm) of pixel (c, r) of slice k, with the slices along @p sign x normal.
    Eigen::Vector3d worldMm(int c, int r, int k, double sign) const {
        return firstMm + c * kColSpacing * rowCosine() + r * kRowSpacing * columnCosine() +
               k * kSliceSpacing * sign * normal();
    }
};

/// A Siemens CSA header (SV10) with the given elements, each a list of text items.
std::string csaHeader(const std::vector<std::pair<std::string, std::vector<std::string>>>& tags) {
    std::string out = std::string("SV10\4\3\2\1", 8);
    const auto put32 = [&](std::int32_t v) { out.append(reinterpret_cast<const char*>(&v), 4); };
    put32(static_cast<std::int32_t>(tags.size()));
    put32(77);
    for (const auto& [name, items] : tags) {
        std::string field(64, '\0');
        std::memcpy(field.data(), name.data(), name.size());
        out += field;
        put32(static_cast<std::int32_t>(items.size()));  // VM
        out += std::string("FD\0\0", 4);
        put32(4);  // SyngoDT
        put32(static_cast<std::int32_t>(items.size()));
        put32(77);
        for (const std::string& item : items) {
            const auto n = static_cast<std::int32_t>(item.size() + 1);
            put32(n);
            put32(n);
            put32(77);
            put32(n);
            out += item;
            out.append(static_cast<std::size_t>((4 - n % 4) % 4) + 1, '\0');
        }
    }
    return out;
}

std::string num(double v) {
    char buf[32];
    std::snprintf(buf, sizeof buf, "%.8f", v);
    return buf;
}

/// How a mosaic file is laid out and stored.
struct MosaicSpec {
    int tileCols = Known::kCols, tileRows = Known::kRows, slices = Known::kSlices,
        grid = Known::kGrid;
    int imagesInMosaic = Known::kSlices;  ///< the value of (0019,100A)
    bool csaCount = true;                 ///< the CSA header also holds NumberOfImagesInMosaic
    gdcm::TransferSyntax::TSType syntax = gdcm::TransferSyntax::ExplicitVRLittleEndian;
};

/// Writes time point @p t of the known geometry as one MOSAIC file of layout @p spec, tile k
/// holding Known::value(c, r, k, t); the CSA normal is the plane's normal times @p sign (Siemens
/// stores descending slices with the normal reversed).
void writeMosaicFile(const Known& known, const MosaicSpec& spec, const fs::path& file, int t,
                     double sign, const std::string& seriesUid) {
    const int cols = spec.tileCols * spec.grid, rows = spec.tileRows * spec.grid;
    std::vector<std::int16_t> pixels(static_cast<std::size_t>(cols * rows), 0);
    for (int k = 0; k < spec.slices; ++k) {
        const int c0 = (k % spec.grid) * spec.tileCols, r0 = (k / spec.grid) * spec.tileRows;
        for (int r = 0; r < spec.tileRows; ++r)
            for (int c = 0; c < spec.tileCols; ++c)
                pixels[static_cast<std::size_t>((r0 + r) * cols + c0 + c)] =
                    Known::value(c, r, k, t);
    }
    palp::test::DicomImage image;
    image.cols = cols;
    image.rows = rows;
    image.pixels = palp::test::storedWords(pixels);
    const Eigen::Vector3d u = known.rowCosine(), v = known.columnCosine();
    image.cosines = {u.x(), u.y(), u.z(), v.x(), v.y(), v.z()};
    // The third spacing is written as Spacing Between Slices.
    image.spacingMm = {Known::kColSpacing, Known::kRowSpacing, Known::kSliceSpacing};
    // Image Position (Patient) of a mosaic: the corner of a tile-sized image centred on the
    // whole mosaic, i.e. the first slice's corner moved back by half the extra columns and rows.
    const Eigen::Vector3d ipp = known.firstMm -
                                u * Known::kColSpacing * (cols - spec.tileCols) / 2.0 -
                                v * Known::kRowSpacing * (rows - spec.tileRows) / 2.0;
    image.positionMm = {ipp.x(), ipp.y(), ipp.z()};
    image.syntax = spec.syntax;
    palp::test::writeDicomImage(file, image, [&](gdcm::DataSet& ds) {
        using palp::test::setBytes;
        using palp::test::setText;
        setText(ds, 0x0008, 0x0008, gdcm::VR::CS, "ORIGINAL\\PRIMARY\\M\\ND\\MOSAIC");
        setText(ds, 0x0008, 0x0070, gdcm::VR::LO, "SIEMENS");
        setText(ds, 0x0008, 0x0032, gdcm::VR::TM, "1200" + std::to_string(10 + 2 * t) + ".000000");
        setText(ds, 0x0008, 0x103e, gdcm::VR::LO, "ep2d_bold mosaic");
        setText(ds, 0x0018, 0x0050, gdcm::VR::DS, "3");
        setText(ds, 0x0018, 0x0088, gdcm::VR::DS, num(Known::kSliceSpacing));
        setText(ds, 0x0020, 0x000d, gdcm::VR::UI, seriesUid + ".1");
        setText(ds, 0x0020, 0x000e, gdcm::VR::UI, seriesUid);
        setText(ds, 0x0020, 0x0011, gdcm::VR::IS, "5");
        setText(ds, 0x0020, 0x0012, gdcm::VR::IS, std::to_string(t + 1));
        setText(ds, 0x0020, 0x0013, gdcm::VR::IS, std::to_string(t + 1));
        setText(ds, 0x0019, 0x0010, gdcm::VR::LO, "SIEMENS MR HEADER");
        const auto n = static_cast<std::uint16_t>(spec.imagesInMosaic);
        setBytes(ds, gdcm::Tag(0x0019, 0x100a), gdcm::VR::US,
                 std::string(reinterpret_cast<const char*>(&n), 2));
        setText(ds, 0x0029, 0x0010, gdcm::VR::LO, "SIEMENS CSA HEADER");
        const Eigen::Vector3d sn = sign * known.normal();
        std::vector<std::pair<std::string, std::vector<std::string>>> csaTags;
        if (spec.csaCount)
            csaTags.push_back({"NumberOfImagesInMosaic", {std::to_string(spec.imagesInMosaic)}});
        csaTags.push_back({"SliceNormalVector", {num(sn.x()), num(sn.y()), num(sn.z())}});
        setBytes(ds, gdcm::Tag(0x0029, 0x1010), gdcm::VR::OB, csaHeader(csaTags));
    });
}

/// Writes time point @p t of the known volume as one MOSAIC file (7 slices of 6x5 in a 3x3 grid).
void writeMosaic(const Known& known, const fs::path& file, int t, double sign,
                 const std::string& seriesUid, int imagesInMosaic = Known::kSlices) {
    MosaicSpec spec;
    spec.imagesInMosaic = imagesInMosaic;
    writeMosaicFile(known, spec, file, t, sign, seriesUid);
}

void expectKnownSlices(const Known& known, const SliceStack& st, int t, double sign) {
    ASSERT_EQ(st.slices.size(), static_cast<std::size_t>(Known::kSlices));
    EXPECT_EQ(st.info.originalDims, (std::array<std::int64_t, 3>{6, 5, 7}));
    for (int k = 0; k < Known::kSlices; ++k) {
        const auto& s = st.slices[static_cast<std::size_t>(k)];
        ASSERT_EQ(s.cols, Known::kCols);
        ASSERT_EQ(s.rows, Known::kRows);
        for (int r = 0; r < Known::kRows; ++r) {
            for (int c = 0; c < Known::kCols; ++c) {
                const Eigen::Vector3d p = s.position + c * s.colStep + r * s.rowStep;
                EXPECT_LT((p * 1e3 - known.worldMm(c, r, k, sign)).norm(), 1e-6)
                    << "slice " << k << " pixel " << c << "," << r;
                EXPECT_EQ(s.values[static_cast<std::size_t>(r * Known::kCols + c)],
                          Known::value(c, r, k, t));
            }
        }
    }
}

TEST(DicomMosaic, KnownVolumeRoundTripsExactlyWithEitherSliceDirection) {
    const Known known;
    TempDir tmp;
    for (const double sign : {1.0, -1.0}) {
        const fs::path dir = tmp / (sign > 0 ? "up" : "down");
        fs::create_directories(dir);
        const std::string uid =
            sign > 0 ? "1.2.826.0.1.3680043.2.1125.7.1" : "1.2.826.0.1.3680043.2.1125.7.2";
        writeMosaic(known, dir / "t1.dcm", 0, sign, uid);
        writeMosaic(known, dir / "t2.dcm", 1, sign, uid);
        // As `palp info` counts it: 2 files, 7 positions, 2 time points.
        const auto series = palp::volume::scanDicom({dir});
        ASSERT_EQ(series.size(), 1u);
        EXPECT_EQ(series[0].imageCount, 2);
        EXPECT_EQ(series[0].positionCount, 7);
        EXPECT_EQ(series[0].timePointCount, 2);
        expectThrowWith<palp::ValueError>([&] { palp::volume::readStack({dir}, {}); },
                                          {"one of the 2 time points (0-1)"});
        for (int t = 0; t < 2; ++t) {
            palp::volume::LoadOptions opt;
            opt.timePoint = t;
            const SliceStack st = palp::volume::readStack({dir}, opt);
            expectKnownSlices(known, st, t, sign);
            EXPECT_EQ(st.info.timePointCount, 2);
            EXPECT_EQ(st.info.timePoint, t);
        }
    }
}

TEST(DicomMosaic, SliceCountThatDoesNotTileIsRefused) {
    const Known known;
    TempDir tmp;
    // 10 slices need a 4x4 grid, which 18x15 pixels do not divide into.
    writeMosaic(known, tmp / "m.dcm", 0, 1.0, "1.2.826.0.1.3680043.2.1125.7.3", 10);
    expectThrowWith<palp::FormatError>(
        [&] { palp::volume::readStack({tmp / "m.dcm"}, {}); },
        {(tmp / "m.dcm").string() + ": expected a mosaic of 4x4 equal tiles for 10 slices",
         "18x15"});
}

// Number Of Images In Mosaic (0019,100A) is US: 51 slices are the bytes 33 00, and 0x33 is the
// digit '3'. Read as text (the old reader tried text first and trimmed the NUL), 51 slices became
// 3 tiles of an 8x8 grid, a 344x344x3 grid of the public Siemens mosaic, without a word. The
// layout here is that file's (51 slices in 8x8 tiles; the CSA header without a count, so the tag
// alone decides), with small tiles; once as explicit VR (US declared) and once as implicit VR
// little endian (no VR in the file: the count's known VR and its 2-byte length decide).
TEST(DicomMosaic, CountWhoseLowByteIsAnAsciiDigitIsReadAsUs) {
    const Known known;
    TempDir tmp;
    MosaicSpec spec;
    spec.tileCols = 3;
    spec.tileRows = 2;
    spec.slices = spec.imagesInMosaic = 51;
    spec.grid = 8;
    spec.csaCount = false;
    for (const auto syntax : {gdcm::TransferSyntax::ExplicitVRLittleEndian,
                              gdcm::TransferSyntax::ImplicitVRLittleEndian}) {
        const bool implicit = syntax == gdcm::TransferSyntax::ImplicitVRLittleEndian;
        SCOPED_TRACE(implicit ? "implicit VR" : "explicit VR");
        spec.syntax = syntax;
        const fs::path dir = tmp / (implicit ? "implicit" : "explicit");
        fs::create_directories(dir);
        writeMosaicFile(
            known, spec, dir / "m.dcm", 0, 1.0,
            implicit ? "1.2.826.0.1.3680043.2.1125.7.6" : "1.2.826.0.1.3680043.2.1125.7.5");
        const auto series = palp::volume::scanDicom({dir});
        ASSERT_EQ(series.size(), 1u);
        EXPECT_EQ(series[0].positionCount, 51);
        const SliceStack st = palp::volume::readStack({dir}, {});
        ASSERT_EQ(st.slices.size(), 51u);
        EXPECT_EQ(st.info.originalDims, (std::array<std::int64_t, 3>{3, 2, 51}));
        for (int k = 0; k < 51; ++k) {
            const auto& sl = st.slices[static_cast<std::size_t>(k)];
            ASSERT_EQ(sl.cols, 3);
            ASSERT_EQ(sl.rows, 2);
            for (int r = 0; r < 2; ++r) {
                for (int c = 0; c < 3; ++c) {
                    const Eigen::Vector3d p = sl.position + c * sl.colStep + r * sl.rowStep;
                    EXPECT_LT((p * 1e3 - known.worldMm(c, r, k, 1.0)).norm(), 1e-6)
                        << "slice " << k << " pixel " << c << "," << r;
                    EXPECT_EQ(sl.values[static_cast<std::size_t>(r * 3 + c)],
                              Known::value(c, r, k, 0));
                }
            }
        }
        // The last slice lies 50 spacings along the normal from the first: 165 mm.
        EXPECT_NEAR((st.slices.back().position - st.slices.front().position).norm() * 1e3,
                    50 * Known::kSliceSpacing, 1e-6);
    }
}

TEST(DicomMosaic, CountTagAndCsaHeaderThatDisagreeAreRefused) {
    const Known known;
    TempDir tmp;
    MosaicSpec spec;
    spec.imagesInMosaic = 7;
    writeMosaicFile(known, spec, tmp / "m.dcm", 0, 1.0, "1.2.826.0.1.3680043.2.1125.7.7");
    // The CSA header says 7 too: readable. Now the tag says 9 (still a 3x3 grid).
    ASSERT_EQ(palp::volume::readStack({tmp / "m.dcm"}, {}).slices.size(), 7u);
    gdcm::Reader reader;
    reader.SetFileName((tmp / "m.dcm").c_str());
    ASSERT_TRUE(reader.Read());
    gdcm::DataElement count(gdcm::Tag(0x0019, 0x100a));
    count.SetVR(gdcm::VR::US);
    const std::uint16_t nine = 9;
    count.SetByteValue(reinterpret_cast<const char*>(&nine), 2);
    reader.GetFile().GetDataSet().Replace(count);
    gdcm::Writer writer;
    writer.SetFile(reader.GetFile());
    writer.SetFileName((tmp / "n.dcm").c_str());
    ASSERT_TRUE(writer.Write());
    expectThrowWith<palp::FormatError>(
        [&] { palp::volume::readStack({tmp / "n.dcm"}, {}); },
        {(tmp / "n.dcm").string() + ": expected Number Of Images In Mosaic (0019,100A) and the "
                                    "CSA image header's NumberOfImagesInMosaic to agree, found 9 "
                                    "and 7"});
}

/// Converts one mosaic (CSA normal times @p sign) with dcm2niix and palp; every palp pixel centre
/// must be a dcm2niix voxel centre holding the same value.
void compareWithDcm2niix(double sign) {
    const Known known;
    TempDir tmp;
    fs::create_directories(tmp / "dicom");
    fs::create_directories(tmp / "nifti");
    const std::string uid = "1.2.826.0.1.3680043.2.1125.7.4";
    writeMosaic(known, tmp / "dicom" / "t1.dcm", 0, sign, uid);
    const auto r =
        palp::test::runCommand("dcm2niix -z n -b n -f mosaic -o '" + (tmp / "nifti").string() +
                               "' '" + (tmp / "dicom").string() + "'");
    ASSERT_EQ(r.exitCode, 0) << r.output;
    const fs::path nii = tmp / "nifti" / "mosaic.nii";
    ASSERT_TRUE(fs::exists(nii)) << r.output;
    const std::unique_ptr<nifti_image, void (*)(nifti_image*)> image(
        nifti_image_read(nii.c_str(), 1), nifti_image_free);
    const nifti_image* nim = image.get();
    ASSERT_NE(nim, nullptr);
    ASSERT_EQ(nim->datatype, DT_INT16);
    ASSERT_EQ(nim->nx * nim->ny * nim->nz, Known::kCols * Known::kRows * Known::kSlices);
    const nifti_dmat44 toIndex =
        nifti_dmat44_inverse(nim->sform_code > 0 ? nim->sto_xyz : nim->qto_xyz);
    const auto* data = static_cast<const std::int16_t*>(nim->data);

    const SliceStack st = palp::volume::readStack({tmp / "dicom"}, {});
    ASSERT_EQ(st.slices.size(), static_cast<std::size_t>(Known::kSlices));
    int matched = 0;
    for (const auto& s : st.slices) {
        for (int row = 0; row < s.rows; ++row) {
            for (int col = 0; col < s.cols; ++col) {
                const Eigen::Vector3d lps = (s.position + col * s.colStep + row * s.rowStep) * 1e3;
                const double ras[3] = {-lps.x(), -lps.y(), lps.z()};
                double idx[3];
                for (int a = 0; a < 3; ++a) {
                    idx[a] = toIndex.m[a][0] * ras[0] + toIndex.m[a][1] * ras[1] +
                             toIndex.m[a][2] * ras[2] + toIndex.m[a][3];
                }
                const double ri = std::round(idx[0]), rj = std::round(idx[1]),
                             rk = std::round(idx[2]);
                const auto i = static_cast<std::int64_t>(ri), j = static_cast<std::int64_t>(rj),
                           k = static_cast<std::int64_t>(rk);
                // dcm2niix's voxel centre is palp's pixel centre (its sform is stored as float).
                EXPECT_LT(std::abs(idx[0] - ri) + std::abs(idx[1] - rj) + std::abs(idx[2] - rk),
                          1e-3);
                ASSERT_TRUE(i >= 0 && i < nim->nx && j >= 0 && j < nim->ny && k >= 0 && k < nim->nz)
                    << i << " " << j << " " << k;
                EXPECT_EQ(s.values[static_cast<std::size_t>(row * s.cols + col)],
                          data[static_cast<std::size_t>((k * nim->ny + j) * nim->nx + i)]);
                ++matched;
            }
        }
    }
    EXPECT_EQ(matched, Known::kCols * Known::kRows * Known::kSlices);
}

TEST(DicomMosaic, AgreesWithDcm2niixOnEveryVoxelCentreAndValue) {
    if (!palp::test::haveProgram("dcm2niix")) GTEST_SKIP() << "dcm2niix not installed";
    for (const double sign : {1.0, -1.0}) {
        SCOPED_TRACE(sign > 0 ? "CSA normal along row x column" : "CSA normal reversed");
        compareWithDcm2niix(sign);
    }
}

}  // namespace
