// load() of a DICOM series decodes each slice as the resampler reaches it and releases it
// behind (detail::resampleLazy): the same grid as resampling the whole decoded series, a
// damaged file still refused wherever it lies, and a peak memory that does not grow with the
// series beyond the output grid.
#include <gtest/gtest.h>
#include <malloc.h>

#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <string>

#include "memory_use.h"
#include "palp/base/error.h"
#include "palp/volume/dicom.h"
#include "palp/volume/load.h"
#include "palp/volume/resample.h"
#include "test_support.h"
#include "tilted_series.h"

namespace {

namespace fs = std::filesystem;
using palp::test::TempDir;
using palp::volume::Volume;

/// The generated tilted CT (tests/support/tilted_series.h), turned by @p R, written as DICOM
/// into @p dir.
void writeSeries(const fs::path& dir, int cols, int rows, int slices,
                 const Eigen::Matrix3d& R = Eigen::Matrix3d::Identity()) {
    palp::volume::SliceStack st =
        palp::test::tiltedSeries(cols, rows, slices, 0.5e-3, 0.5e-3, 12.0);
    for (palp::volume::Slice& sl : st.slices) {
        sl.position = R * sl.position;
        sl.colStep = R * sl.colStep;
        sl.rowStep = R * sl.rowStep;
    }
    palp::volume::DicomWriteOptions wo;
    wo.gantryTiltDeg = R.isIdentity() ? 12 : 0;
    palp::volume::writeDicomSeries(st, dir, wo);
}

/// Leaves with different origins, masks or values (every one of a's leaves looked up in b, and
/// the counts compared).
std::size_t leavesDiffering(const Volume& a, const Volume& b) {
    const auto& ta = a.grid->tree();
    const auto& tb = b.grid->tree();
    std::size_t differ = ta.leafCount() > tb.leafCount() ? ta.leafCount() - tb.leafCount()
                                                         : tb.leafCount() - ta.leafCount();
    for (auto it = ta.cbeginLeaf(); it; ++it) {
        const auto* other = tb.probeConstLeaf(it->origin());
        if (!other || other->getValueMask() != it->getValueMask() ||
            std::memcmp(other->buffer().data(), it->buffer().data(), sizeof(float) * it->SIZE) !=
                0) {
            ++differ;
        }
    }
    return differ;
}

void expectSameVolume(const Volume& lazy, const Volume& eager) {
    EXPECT_GT(eager.grid->activeVoxelCount(), 5000u);
    EXPECT_EQ(lazy.grid->activeVoxelCount(), eager.grid->activeVoxelCount());
    EXPECT_EQ(leavesDiffering(lazy, eager), 0u);
    EXPECT_TRUE(lazy.grid->transform() == eager.grid->transform());
    EXPECT_EQ(lazy.grid->background(), eager.grid->background());
    EXPECT_EQ(lazy.info.originalDims, eager.info.originalDims);
    EXPECT_EQ(lazy.info.gantryTiltDeg, eager.info.gantryTiltDeg);
    EXPECT_EQ(lazy.info.sourceDescription, eager.info.sourceDescription);
}

TEST(LazyLoad, GivesTheGridOfTheWholeDecodedSeries) {
    // 90 tilted slices: several groups of blocks, so slices are decoded, released and decoded
    // in bands; at 0.5 mm (the row kernel) and 1.3 mm (a block spans ~13 slices along the
    // normal), and cropped to the middle (slices outside are never read by a block).
    TempDir dir;
    writeSeries(dir.path(), 64, 56, 90);
    const std::vector<fs::path> in{dir.path()};
    const palp::volume::SliceStack decoded = palp::volume::readDicom(in, {});
    for (const double voxel : {0.5e-3, 1.3e-3}) {
        SCOPED_TRACE(voxel);
        palp::volume::LoadOptions opt;
        opt.resample.voxelSize = voxel;
        expectSameVolume(palp::volume::load(in, opt),
                         palp::volume::resample(decoded, opt.resample));
    }
    palp::volume::LoadOptions opt;
    palp::volume::WorldBox box;
    box.min = Eigen::Vector3d(-1, -1, 0.010);
    box.max = Eigen::Vector3d(1, 1, 0.030);
    opt.resample.crop = box;
    expectSameVolume(palp::volume::load(in, opt), palp::volume::resample(decoded, opt.resample));
}

TEST(LazyLoad, GivesTheGridOfAnObliqueSeriesWhoseNormalPointsBackwards) {
    // The band follows the slice normal, not a lattice axis: the same series turned to an
    // oblique sagittal whose normal points along -x (the slices' order runs against the
    // lattice's).
    TempDir dir;
    const Eigen::Matrix3d R = (Eigen::AngleAxisd(-M_PI / 2, Eigen::Vector3d::UnitY()) *
                               Eigen::AngleAxisd(0.3, Eigen::Vector3d::UnitZ()))
                                  .toRotationMatrix();
    writeSeries(dir.path(), 64, 56, 70, R);
    const std::vector<fs::path> in{dir.path()};
    const palp::volume::SliceStack decoded = palp::volume::readDicom(in, {});
    const Eigen::Vector3d n =
        decoded.slices.front().colStep.cross(decoded.slices.front().rowStep).normalized();
    EXPECT_LT(n.x(), -0.5) << "the normal must point backwards along x";
    palp::volume::LoadOptions opt;
    opt.resample.voxelSize = 0.6e-3;
    expectSameVolume(palp::volume::load(in, opt), palp::volume::resample(decoded, opt.resample));
}

TEST(LazyLoad, RefusesADamagedFileOutsideTheCrop) {
    // The last slice's pixel data cut short: no block of the cropped grid reads it, yet load()
    // refuses the series as readDicom() does, naming the file.
    TempDir dir;
    writeSeries(dir.path(), 64, 56, 40);
    std::vector<fs::path> files;
    for (const auto& e : fs::directory_iterator(dir.path())) files.push_back(e.path());
    ASSERT_EQ(files.size(), 40u);
    // The slice farthest along z: the series' files are named in slice order.
    std::sort(files.begin(), files.end());
    const fs::path damaged = files.back();
    fs::resize_file(damaged, fs::file_size(damaged) - 1000);
    palp::volume::LoadOptions opt;
    palp::volume::WorldBox box;
    box.min = Eigen::Vector3d(-1, -1, -1);
    box.max = Eigen::Vector3d(1, 1, 0.004);
    opt.resample.crop = box;
    palp::test::expectThrowWith<palp::FormatError>([&] { palp::volume::load({dir.path()}, opt); },
                                                   {damaged.string(), "truncated"});
}

TEST(LazyLoad, PeakMemoryGrowsWithTheGridNotWithTheSeries) {
    // The scale test, small: 256 x 256 tilted slices, 80 and then 320 of them. Holding
    // the decoded series as float (21 and 84 MB) beside the grid would add 63 MB from one to
    // the other, twice what the grid adds; load() holds the grid and a band of slices, so its
    // peak (above what was resident before) grows by at most 1.5x what the grid grows, and at
    // 320 slices is within 1.5x the grid. (At 80 slices the band and the threads' buffers, a
    // few MB that do not grow with the series, are a larger part of an 8 MB grid.)
#if defined(__SANITIZE_ADDRESS__) || defined(__SANITIZE_THREAD__)
    GTEST_SKIP() << "the sanitizer's shadow memory and quarantine change the resident set";
#endif
    double peaks[2] = {0, 0}, grids[2] = {0, 0};
    const int sizes[2] = {80, 320};
    for (int i = 0; i < 2; ++i) {
        const int slices = sizes[i];
        SCOPED_TRACE(slices);
        TempDir dir;
        writeSeries(dir.path(), 256, 256, slices);
        malloc_trim(0);  // the generated series is gone: its pages must not serve load()
        std::ofstream("/proc/self/clear_refs") << "5";  // resets VmHWM to the current RSS
        const auto [before, peak0] = palp::test::rssAndPeak();
        if (std::abs(peak0 - before) > 4e6) GTEST_SKIP() << "this kernel cannot reset VmHWM";
        const Volume v = palp::volume::load({dir.path()});
        const auto [after, peak] = palp::test::rssAndPeak();
        grids[i] = static_cast<double>(v.grid->memUsage());
        peaks[i] = peak - before;
        std::printf(
            "%d slices: peak %.1f MB above before, grid %.1f MB (%.2fx), input as float "
            "%.1f MB\n",
            slices, peaks[i] / 1e6, grids[i] / 1e6, peaks[i] / grids[i],
            256.0 * 256.0 * slices * sizeof(float) / 1e6);
        EXPECT_GT(after - before, 0.8 * grids[i]) << "the grid lives in this process";
    }
    const double inputGrowth = 256.0 * 256.0 * (sizes[1] - sizes[0]) * sizeof(float);
    ASSERT_GT(inputGrowth, 1.5 * (grids[1] - grids[0])) << "the test must tell a held series";
    EXPECT_LE(peaks[1] - peaks[0], 1.5 * (grids[1] - grids[0]))
        << "peak grew " << (peaks[1] - peaks[0]) / 1e6 << " MB, the grid "
        << (grids[1] - grids[0]) / 1e6 << " MB";
    EXPECT_LE(peaks[1], 1.5 * grids[1])
        << "peak " << peaks[1] / 1e6 << " MB over a " << grids[1] / 1e6 << " MB grid";
}

}  // namespace
