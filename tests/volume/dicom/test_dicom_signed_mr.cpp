// Signed MR values survive conversion (issue 37): a field map in Hz (signed int16 storage, as
// GE and Siemens write them) and a phase image (Siemens: unsigned 12-bit storage, slope 2,
// intercept -4096, so -4096..4094) keep every voxel with the source's value. The old MR
// background threshold 0 deactivated every negative value (a public field map kept 28,515 of
// 141,900 voxels). A threshold given explicitly still applies, and the values it takes away are
// counted and reported by palp convert.
#include <gdcmMediaStorage.h>
#include <gdcmReader.h>
#include <gdcmUIDGenerator.h>
#include <gtest/gtest.h>

#include <cmath>
#include <cstdint>
#include <functional>
#include <string>
#include <vector>

#include "dicom_test_writer.h"
#include "palp/volume/dicom.h"
#include "palp/volume/load.h"
#include "palp/volume/resample.h"
#include "test_support.h"

namespace {

namespace fs = std::filesystem;
using palp::test::TempDir;

constexpr int kCols = 20, kRows = 16, kSlices = 6;
constexpr double kMm = 2.0;  // pixel spacing and slice gap: the grid's voxels are the pixels

/// A field map in Hz: -250..250 over the volume, zero nowhere but at a few voxels.
std::int16_t fieldMapHz(int c, int r, int k) {
    return static_cast<std::int16_t>(
        std::lround(250.0 * std::sin(0.4 * c + 0.3 * k) * std::cos(0.35 * r - 0.2 * k)));
}

/// How a series stores its values.
struct Storage {
    bool isSigned = true;  ///< int16, else uint16 with 12 bits stored
    std::string slope = "1", intercept = "0";
};

/// Writes an axial MR series of stored pixels @p stored(c, r, k) as @p storage says, 2 mm pixels,
/// slices 2 mm apart.
void writeSeries(const fs::path& dir, const std::function<int(int, int, int)>& stored,
                 const Storage& storage) {
    fs::create_directories(dir);
    gdcm::UIDGenerator gen;
    const std::string series = gen.Generate();
    for (int k = 0; k < kSlices; ++k) {
        palp::test::DicomImage image;
        image.cols = kCols;
        image.rows = kRows;
        for (int r = 0; r < kRows; ++r)
            for (int c = 0; c < kCols; ++c)
                image.pixels.push_back(static_cast<std::uint16_t>(stored(c, r, k)));
        if (!storage.isSigned) image.format = gdcm::PixelFormat(1, 16, 12, 11, 0);
        image.spacingMm = {kMm, kMm, kMm};
        image.positionMm = {-20.0, -16.0, kMm * k};
        palp::test::writeDicomImage(
            dir / ("f" + std::to_string(k) + ".dcm"), image, [&](gdcm::DataSet& ds) {
                using palp::test::setText;
                setText(ds, 0x0008, 0x0008, gdcm::VR::CS, "ORIGINAL\\PRIMARY\\B0 MAP");
                setText(ds, 0x0008, 0x103e, gdcm::VR::LO, "field map Hz");
                setText(ds, 0x0020, 0x000d, gdcm::VR::UI, series + ".1");
                setText(ds, 0x0020, 0x000e, gdcm::VR::UI, series);
                setText(ds, 0x0020, 0x0013, gdcm::VR::IS, std::to_string(k + 1));
                setText(ds, 0x0028, 0x1052, gdcm::VR::DS, storage.intercept);
                setText(ds, 0x0028, 0x1053, gdcm::VR::DS, storage.slope);
            });
    }
}

/// What a volume holds at the source's pixels.
struct Kept {
    int equal = 0, active = 0, total = 0;
};

/// Reads @p vol at every source pixel centre (which are voxel centres here).
Kept compare(const palp::volume::Volume& vol, const std::function<double(int, int, int)>& value) {
    Kept kept;
    const auto acc = vol.grid->getConstAccessor();
    for (int k = 0; k < kSlices; ++k) {
        for (int r = 0; r < kRows; ++r) {
            for (int c = 0; c < kCols; ++c) {
                const openvdb::Vec3d world((-20.0 + kMm * c) * 1e-3, (-16.0 + kMm * r) * 1e-3,
                                           kMm * k * 1e-3);
                const openvdb::Vec3d x = vol.grid->transform().worldToIndex(world);
                const openvdb::Coord ijk(static_cast<int>(std::lround(x.x())),
                                         static_cast<int>(std::lround(x.y())),
                                         static_cast<int>(std::lround(x.z())));
                EXPECT_LT((x - ijk.asVec3d()).length(), 1e-6) << "not on a voxel centre";
                ++kept.total;
                // Equal up to the resampler's double rounding (a voxel centre lies on its
                // slice to ~1e-16 m, so a 0 may come back as 1e-13).
                if (std::abs(acc.getValue(ijk) - value(c, r, k)) <= 1e-9) {
                    ++kept.equal;
                }
                if (acc.isValueOn(ijk)) ++kept.active;
            }
        }
    }
    return kept;
}

TEST(DicomSignedMr, FieldMapKeepsEveryVoxelAndValue) {
    TempDir tmp;
    writeSeries(tmp / "fmap", fieldMapHz, {});
    int negative = 0, zero = 0;
    for (int k = 0; k < kSlices; ++k)
        for (int r = 0; r < kRows; ++r)
            for (int c = 0; c < kCols; ++c) {
                negative += fieldMapHz(c, r, k) < 0 ? 1 : 0;
                zero += fieldMapHz(c, r, k) == 0 ? 1 : 0;
            }
    ASSERT_GT(negative, kCols * kRows * kSlices / 3);
    const auto vol = palp::volume::load({tmp / "fmap"}, {});
    EXPECT_EQ(vol.info.modality, "MR");
    EXPECT_NEAR(vol.voxelSize(), kMm * 1e-3, 1e-12);
    EXPECT_EQ(vol.info.backgroundThreshold, palp::volume::kNoBackgroundThreshold);
    EXPECT_EQ(vol.info.valuesBelowThreshold, 0u);
    EXPECT_EQ(vol.grid->background(), 0.0f);
    const Kept kept = compare(vol, [](int c, int r, int k) { return fieldMapHz(c, r, k); });
    EXPECT_EQ(kept.total, kCols * kRows * kSlices);
    EXPECT_EQ(kept.equal, kept.total);
    // Every voxel but the zeros (the background, which read back as 0 when inactive) is active.
    EXPECT_GE(kept.active, kept.total - zero);

    // The old default, asked for explicitly: the negative values go, and are counted.
    palp::volume::LoadOptions opt;
    opt.resample.backgroundThreshold = 0.0f;
    const auto cut = palp::volume::load({tmp / "fmap"}, opt);
    EXPECT_EQ(cut.info.valuesBelowThreshold, static_cast<std::uint64_t>(negative));
    const Kept left = compare(cut, [](int c, int r, int k) { return fieldMapHz(c, r, k); });
    EXPECT_EQ(left.equal, left.total - negative);
}

TEST(DicomSignedMr, PhaseImageKeepsItsWholeRange) {
    // Siemens phase: stored 0..4095 (unsigned), slope 2, intercept -4096: -4096..4094.
    const auto phase = [](int c, int r, int k) {
        return -4096.0 + 2.0 * ((c * 211 + r * 97 + k * 1409) % 4096);
    };
    TempDir tmp;
    Storage storage;
    storage.isSigned = false;
    storage.slope = "2";
    storage.intercept = "-4096";
    writeSeries(
        tmp / "phase",
        [&](int c, int r, int k) {
            return static_cast<int>(std::lround((phase(c, r, k) + 4096) / 2));
        },
        storage);
    const auto vol = palp::volume::load({tmp / "phase"}, {});
    EXPECT_EQ(vol.info.valuesBelowThreshold, 0u);
    const Kept kept = compare(vol, phase);
    EXPECT_EQ(kept.equal, kept.total);
    // The grid's extremes are the source's: both halves of the range are there.
    double lo = 0, hi = 0, sourceLo = 0, sourceHi = 0;
    for (auto it = vol.grid->cbeginValueOn(); it; ++it) {
        lo = std::min(lo, static_cast<double>(*it));
        hi = std::max(hi, static_cast<double>(*it));
    }
    for (int k = 0; k < kSlices; ++k)
        for (int r = 0; r < kRows; ++r)
            for (int c = 0; c < kCols; ++c) {
                sourceLo = std::min(sourceLo, phase(c, r, k));
                sourceHi = std::max(sourceHi, phase(c, r, k));
            }
    EXPECT_LT(sourceLo, -4000.0);
    EXPECT_GT(sourceHi, 4000.0);
    EXPECT_NEAR(lo, sourceLo, 1e-9);
    EXPECT_NEAR(hi, sourceHi, 1e-9);
}

TEST(DicomSignedMr, ConvertReportsWhatTheThresholdTakes) {
    const fs::path tool = palp::test::palpTool();
    if (!fs::exists(tool)) GTEST_SKIP() << "palp tool not built at " << tool;
    TempDir tmp;
    writeSeries(tmp / "fmap", fieldMapHz, {});
    int negative = 0;
    for (int k = 0; k < kSlices; ++k)
        for (int r = 0; r < kRows; ++r)
            for (int c = 0; c < kCols; ++c) negative += fieldMapHz(c, r, k) < 0 ? 1 : 0;
    const std::string convert = "'" + tool.string() + "' convert '" + (tmp / "fmap").string() +
                                "' -o '" + (tmp / "f.vdb").string() + "'";
    auto r = palp::test::runCommand(convert);
    ASSERT_EQ(r.exitCode, 0) << r.output;
    EXPECT_NE(r.output.find("no background threshold: no source value deactivated"),
              std::string::npos)
        << r.output;
    r = palp::test::runCommand(convert + " --background 0");
    ASSERT_EQ(r.exitCode, 0) << r.output;
    EXPECT_NE(r.output.find("background threshold 0: " + std::to_string(negative) +
                            " source values below it now read as the background 0"),
              std::string::npos)
        << r.output;
    // The count travels with the file.
    EXPECT_EQ(palp::volume::loadVdb(tmp / "f.vdb").info.valuesBelowThreshold,
              static_cast<std::uint64_t>(negative));
}

TEST(DicomSignedMr, WriteDicomSeriesKeepsAnMrRescaleAndItsPlane) {
    // GDCM turns a classic MR image with a rescale into an Enhanced MR one, its Image Position
    // inside functional groups; writeDicomSeries() keeps MR Image Storage with the plane at the
    // top level, and the series reads back exactly.
    TempDir tmp;
    palp::volume::SliceStack st;
    st.info.modality = "MR";
    for (int k = 0; k < 3; ++k) {
        palp::volume::Slice s;
        s.cols = 5;
        s.rows = 4;
        s.colStep = {1e-3, 0, 0};
        s.rowStep = {0, 1.5e-3, 0};
        s.position = {-2e-3, 3e-3, 2e-3 * k};
        for (int i = 0; i < s.cols * s.rows; ++i)
            s.values.push_back(static_cast<float>(2 * (i + 30 * k) - 100));
        st.slices.push_back(s);
    }
    palp::volume::DicomWriteOptions wo;
    wo.modality = "MR";
    wo.rescaleSlope = 2;
    wo.rescaleIntercept = -100;
    palp::volume::writeDicomSeries(st, tmp / "mr", wo);
    gdcm::Reader reader;
    reader.SetFileName((tmp / "mr" / "IMG0002.dcm").c_str());
    ASSERT_TRUE(reader.Read());
    const gdcm::DataSet& ds = reader.GetFile().GetDataSet();
    const auto text = [&](std::uint16_t g, std::uint16_t e) {
        const gdcm::Tag tag(g, e);
        if (!ds.FindDataElement(tag) || !ds.GetDataElement(tag).GetByteValue())
            return std::string();
        const gdcm::ByteValue* bv = ds.GetDataElement(tag).GetByteValue();
        std::string v(bv->GetPointer(), bv->GetLength());
        while (!v.empty() && (v.back() == ' ' || v.back() == '\0')) v.pop_back();
        return v;
    };
    EXPECT_EQ(text(0x0008, 0x0016),
              gdcm::MediaStorage::GetMSString(gdcm::MediaStorage::MRImageStorage));
    EXPECT_EQ(text(0x0020, 0x0032), "-2\\3\\2");
    EXPECT_EQ(text(0x0028, 0x1053), "2");
    const palp::volume::SliceStack back = palp::volume::readStack({tmp / "mr"}, {});
    ASSERT_EQ(back.slices.size(), 3u);
    for (std::size_t k = 0; k < 3; ++k) {
        EXPECT_LE((back.slices[k].position - st.slices[k].position).norm(), 1e-9) << k;
        EXPECT_EQ(back.slices[k].values, st.slices[k].values) << k;
    }
}

}  // namespace
