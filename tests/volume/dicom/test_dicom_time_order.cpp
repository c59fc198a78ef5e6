// The time order of a classic (one image per file) 4D series: which image of each slice position
// belongs to which time point. Series made at test time in the layout of a Philips classic DTI
// export (a b = 0 and a b = 1000 volume, Instance Numbers in acquisition order, Acquisition
// Number not constant over a volume), of a series whose instance numbers restart with each
// acquisition, and of one whose keys cannot tell the order at all.
#include <gtest/gtest.h>

#include <cstdint>
#include <cstdio>
#include <functional>
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

constexpr int kCols = 4, kRows = 3, kPositions = 12;
constexpr double kPixelMm = 2.0, kGapMm = 3.0;

/// The stored value of pixel (c, r) at position k of time point t: b = 0 images are bright,
/// diffusion-weighted ones dark, as in a DTI series.
std::int16_t value(int c, int r, int k, int t) {
    return static_cast<std::int16_t>((t == 0 ? 2000 : 300 * t) + 10 * k + 4 * r + c);
}

/// The tags of one image that decide its time point.
struct ImageKeys {
    int instance = 1;
    int acquisition = 1;
    double bValue = 0;
    double gradient[3] = {0, 0, 0};
    std::string acquisitionTime = "101530.12";  // one for the whole series, as Philips gives it
};

/// Writes the image of position @p k, time point @p t, an axial 4x3 slice k x 3 mm up, with the
/// time keys @p keys (explicit VR little endian, as the Philips files are).
void writeImage(const fs::path& file, int k, int t, const ImageKeys& keys,
                const std::string& seriesUid) {
    palp::test::DicomImage image;
    image.cols = kCols;
    image.rows = kRows;
    for (int r = 0; r < kRows; ++r)
        for (int c = 0; c < kCols; ++c)
            image.pixels.push_back(static_cast<std::uint16_t>(value(c, r, k, t)));
    image.spacingMm = {kPixelMm, kPixelMm, kGapMm};
    image.positionMm = {-3.0, -2.0, kGapMm * k};
    palp::test::writeDicomImage(file, image, [&](gdcm::DataSet& ds) {
        using palp::test::setDoubles;
        using palp::test::setText;
        setText(ds, 0x0008, 0x0008, gdcm::VR::CS, "ORIGINAL\\PRIMARY\\M_SE\\M\\SE");
        setText(ds, 0x0008, 0x0070, gdcm::VR::LO, "Philips Medical Systems");
        setText(ds, 0x0008, 0x0032, gdcm::VR::TM, keys.acquisitionTime);
        setText(ds, 0x0008, 0x103e, gdcm::VR::LO, "DTI_low_iso");
        setText(ds, 0x0018, 0x0050, gdcm::VR::DS, "3");
        setText(ds, 0x0020, 0x000d, gdcm::VR::UI, seriesUid + ".1");
        setText(ds, 0x0020, 0x000e, gdcm::VR::UI, seriesUid);
        setText(ds, 0x0020, 0x0011, gdcm::VR::IS, "1001");
        setText(ds, 0x0020, 0x0012, gdcm::VR::IS, std::to_string(keys.acquisition));
        setText(ds, 0x0020, 0x0013, gdcm::VR::IS, std::to_string(keys.instance));
        setText(ds, 0x0020, 0x0100, gdcm::VR::IS, "1");  // Temporal Position Identifier
        setDoubles(ds, 0x0018, 0x9087, {keys.bValue});
        setDoubles(ds, 0x0018, 0x9089, {keys.gradient[0], keys.gradient[1], keys.gradient[2]});
    });
}

/// Writes a series of kPositions positions x 2 time points into @p dir, the keys of each image
/// from @p keysOf(k, t); files named by a number that follows neither position nor time.
void writeSeries(const fs::path& dir, const std::string& uid,
                 const std::function<ImageKeys(int k, int t)>& keysOf, int timePoints = 2,
                 const std::function<bool(int k, int t)>& present = {}) {
    fs::create_directories(dir);
    for (int k = 0; k < kPositions; ++k) {
        for (int t = 0; t < timePoints; ++t) {
            if (present && !present(k, t)) continue;
            char name[32];
            std::snprintf(name, sizeof name, "IM_%04d", (k * 7 + t * 13) % 97 + 100 * t);
            writeImage(dir / name, k, t, keysOf(k, t), uid);
        }
    }
}

/// Every slice of time point @p t holds that time point's values, at its position.
void expectTimePoint(const fs::path& dir, int t, int timePoints = 2) {
    palp::volume::LoadOptions opt;
    opt.timePoint = t;
    const SliceStack st = palp::volume::readStack({dir}, opt);
    ASSERT_EQ(st.slices.size(), static_cast<std::size_t>(kPositions));
    EXPECT_EQ(st.info.timePoint, t);
    EXPECT_EQ(st.info.timePointCount, timePoints);
    int wrong = 0;
    for (int k = 0; k < kPositions; ++k) {
        const auto& s = st.slices[static_cast<std::size_t>(k)];
        EXPECT_NEAR(s.position.z() * 1e3, kGapMm * k, 1e-9);
        bool ok = true;
        for (int r = 0; r < kRows; ++r)
            for (int c = 0; c < kCols; ++c)
                ok = ok && s.values[static_cast<std::size_t>(r * kCols + c)] == value(c, r, k, t);
        if (!ok) ++wrong;
    }
    EXPECT_EQ(wrong, 0) << "positions of time point " << t << " holding another time point";
}

/// Philips classic DTI: instance numbers in acquisition order (the two images of a position
/// next to each other), Acquisition Number 19 for most images but 22 for the b = 0 images of
/// every fourth position. Ordered by Acquisition Number first (the old rule), those positions
/// put their b = 1000 image into time point 0: 3 of 12 positions wrong, exit 0.
ImageKeys philipsDti(int k, int t) {
    ImageKeys keys;
    keys.instance = 2 * k + t + 1;
    keys.acquisition = t == 0 && k % 4 == 1 ? 22 : 19;
    keys.bValue = t == 0 ? 0 : 1000;
    if (t == 1) {
        keys.gradient[0] = 0.6;
        keys.gradient[1] = 0.8;
    }
    return keys;
}

TEST(DicomTimeOrder, VaryingAcquisitionNumberDoesNotMixDiffusionVolumes) {
    TempDir tmp;
    writeSeries(tmp / "dti", "1.2.826.0.1.3680043.2.1125.37.1", philipsDti);
    const auto series = palp::volume::scanDicom({tmp / "dti"});
    ASSERT_EQ(series.size(), 1u);
    EXPECT_EQ(series[0].positionCount, kPositions);
    EXPECT_EQ(series[0].timePointCount, 2);
    expectTimePoint(tmp / "dti", 0);
    expectTimePoint(tmp / "dti", 1);
}

TEST(DicomTimeOrder, InstanceNumbersRestartingPerAcquisitionOrderedByAcquisitionNumber) {
    // Each volume its own acquisition whose instance numbers restart at 1: Instance Number
    // repeats at every position, so Acquisition Number orders the time points.
    TempDir tmp;
    writeSeries(tmp / "s", "1.2.826.0.1.3680043.2.1125.37.2", [](int k, int t) {
        ImageKeys keys = philipsDti(k, t);
        keys.instance = k + 1;
        keys.acquisition = t + 1;
        return keys;
    });
    expectTimePoint(tmp / "s", 0);
    expectTimePoint(tmp / "s", 1);
}

TEST(DicomTimeOrder, TimePointThatWouldMixDiffusionWeightingsIsRefused) {
    // At position 5 the b = 1000 image has the smaller instance number (and the smaller
    // acquisition number): no key orders it after the b = 0 image. Reading time point 0 would
    // give a volume with one diffusion-weighted slice; it is refused, naming both images.
    TempDir tmp;
    writeSeries(tmp / "s", "1.2.826.0.1.3680043.2.1125.37.3", [](int k, int t) {
        ImageKeys keys = philipsDti(k, t);
        if (k == 5) keys.instance = 2 * k + (1 - t) + 1;
        return keys;
    });
    for (const int t : {0, 1}) {
        palp::volume::LoadOptions opt;
        opt.timePoint = t;
        expectThrowWith<palp::ValueError>(
            [&] { palp::volume::readStack({tmp / "s"}, opt); },
            {"expected one diffusion weighting per time point, found b = 0 s/mm^2, gradient "
             "(0\\0\\0) in ",
             "and b = 1000 s/mm^2, gradient (0.6\\0.8\\0) in ", "at time point 0",
             "(images ordered by Temporal Position Identifier 1, Instance Number 11)"});
    }
}

/// A GE-like 4D series of 3 time points (instance numbers volume after volume, one Acquisition
/// Number, each image its own acquisition time, 0.5 s apart within a volume, 10 s between
/// volumes); @p present says which images exist.
void writeTimedSeries(const fs::path& dir, const std::string& uid,
                      const std::function<bool(int k, int t)>& present) {
    writeSeries(
        dir, uid,
        [](int k, int t) {
            ImageKeys keys;
            keys.instance = t * kPositions + k + 1;
            char time[32];
            std::snprintf(time, sizeof time, "1015%05.2f", 10.0 * t + 0.5 * k);
            keys.acquisitionTime = time;
            return keys;
        },
        3, present);
}

TEST(DicomTimeOrder, SeriesStoppedEarlyConvertsItsCompleteTimePoints) {
    // The third volume holds only 10 of 12 positions: time points 0 and 1 are whole.
    TempDir tmp;
    writeTimedSeries(tmp / "s", "1.2.826.0.1.3680043.2.1125.37.4",
                     [](int k, int t) { return t < 2 || k < 10; });
    expectTimePoint(tmp / "s", 0, 3);
    expectTimePoint(tmp / "s", 1, 3);
    palp::volume::LoadOptions opt;
    opt.timePoint = 2;
    expectThrowWith<palp::ValueError>(
        [&] { palp::volume::readStack({tmp / "s"}, opt); },
        {"expected time point 2 at every slice position, found 2 images at that of ",
         "(the series is incomplete)"});
    // Without a time point the series is refused as before, naming the odd position.
    expectThrowWith<palp::ValueError>(
        [&] { palp::volume::readStack({tmp / "s"}, {}); },
        {"expected the same number of images at every slice position (3 at 10 of 12 "
         "positions), found 2"});
}

TEST(DicomTimeOrder, SeriesMissingAnImageWithinIsRefusedWhereItMatters) {
    // Position 5 lacks its image of time point 1: its rank-1 image is time point 2's.
    TempDir tmp;
    writeTimedSeries(tmp / "s", "1.2.826.0.1.3680043.2.1125.37.5",
                     [](int k, int t) { return !(k == 5 && t == 1); });
    expectTimePoint(tmp / "s", 0, 3);  // the images before the gap are whole
    palp::volume::LoadOptions opt;
    opt.timePoint = 1;
    expectThrowWith<palp::ValueError>(
        [&] { palp::volume::readStack({tmp / "s"}, opt); },
        {"expected the images of time point 1 acquired before those of time point 2",
         "an image is missing within the series, or the tags cannot tell"});
}

}  // namespace
