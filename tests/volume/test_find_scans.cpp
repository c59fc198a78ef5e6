// findScans (palp/volume/find_scans.h): the scans under a folder as `palp convert-tree` takes
// them. A series split over two folders is one scan (at their common folder), two series in
// one folder are two, the other formats are one scan per file, a skipped folder is not
// searched, a damaged file goes with its series, and unreadable files of no series are a scan
// of their own; each scan's files load() as the series alone.
#include <gtest/gtest.h>

#include <algorithm>
#include <filesystem>
#include <fstream>
#include <string>
#include <vector>

#include "palp/base/error.h"
#include "palp/volume/dicom.h"
#include "palp/volume/find_scans.h"
#include "palp/volume/load.h"
#include "test_support.h"
#include "tilted_series.h"

namespace {

namespace fs = std::filesystem;
using palp::test::TempDir;
using palp::volume::FoundScan;

void writeSeries(const fs::path& dir, int slices, const std::string& description) {
    palp::volume::DicomWriteOptions wo;
    wo.seriesDescription = description;
    palp::volume::writeDicomSeries(palp::test::tiltedSeries(24, 20, slices, 1e-3, 1e-3, 0), dir,
                                   wo);
}

std::vector<fs::path> filesIn(const fs::path& dir) {
    std::vector<fs::path> files;
    for (const auto& e : fs::directory_iterator(dir)) files.push_back(e.path());
    std::sort(files.begin(), files.end());
    return files;
}

/// A minimal MetaImage (2 x 2 x 2 uint8, data inline).
void writeMetaImage(const fs::path& file) {
    std::ofstream out(file, std::ios::binary);
    out << "ObjectType = Image\nNDims = 3\nDimSize = 2 2 2\nElementSpacing = 1 1 1\n"
           "ElementType = MET_UCHAR\nElementDataFile = LOCAL\n";
    out << std::string(8, '\x05');
}

TEST(FindScans, GroupsSeriesByUidAcrossFoldersAndListsOtherFormats) {
    TempDir tmp;
    const fs::path root = tmp / "archive";
    // Series "split": its slices moved half into a/part1, half into a/part2.
    writeSeries(tmp / "split", 10, "split");
    const std::vector<fs::path> split = filesIn(tmp / "split");
    fs::create_directories(root / "a" / "part1");
    fs::create_directories(root / "a" / "part2");
    for (std::size_t i = 0; i < split.size(); ++i)
        fs::rename(split[i], root / "a" / (i < 5 ? "part1" : "part2") / split[i].filename());
    // Two series in one folder.
    fs::create_directories(root / "b" / "mixed");
    for (const char* name : {"x", "y"}) {
        writeSeries(tmp / name, 6, name);
        for (const fs::path& f : filesIn(tmp / name))
            fs::rename(f, root / "b" / "mixed" / (std::string(name) + f.filename().string()));
    }
    fs::create_directories(root / "c");
    writeMetaImage(root / "c" / "scan.mha");
    std::ofstream(root / "c" / "notes.txt") << "not a scan";
    // A folder left out (an output folder inside the input, say).
    writeSeries(root / "out" / "old", 6, "old");

    const std::vector<FoundScan> found = palp::volume::findScans(root, {root / "out"});
    ASSERT_EQ(found.size(), 4u);
    EXPECT_EQ(found[0].folder, root / "a");  // the split series, at its common folder
    EXPECT_EQ(found[0].format, palp::volume::Format::Dicom);
    EXPECT_EQ(found[0].description, "split");
    EXPECT_EQ(found[0].modality, "CT");
    EXPECT_EQ(found[0].imageCount, 10);
    EXPECT_EQ(found[0].files.size(), 10u);
    EXPECT_TRUE(std::is_sorted(found[0].files.begin(), found[0].files.end()));
    EXPECT_EQ(found[1].folder, root / "b" / "mixed");
    EXPECT_EQ(found[2].folder, root / "b" / "mixed");
    EXPECT_NE(found[1].seriesUid, found[2].seriesUid);
    EXPECT_LT(found[1].seriesUid, found[2].seriesUid);
    EXPECT_EQ(found[1].files.size() + found[2].files.size(), 12u);
    EXPECT_EQ(found[3].format, palp::volume::Format::MetaImage);
    EXPECT_EQ(found[3].files, std::vector<fs::path>{root / "c" / "scan.mha"});
    EXPECT_EQ(found[3].folder, root / "c");
    for (const FoundScan& s : found) EXPECT_FALSE(s.unreadable);

    // Each scan's files read as that series alone.
    palp::volume::LoadOptions opt;
    opt.seriesUid = found[1].seriesUid;
    const palp::volume::SliceStack alone = palp::volume::readStack(found[1].files, opt);
    const palp::volume::SliceStack fromFolder =
        palp::volume::readStack({root / "b" / "mixed"}, opt);
    ASSERT_EQ(alone.slices.size(), fromFolder.slices.size());
    for (std::size_t i = 0; i < alone.slices.size(); ++i)
        EXPECT_EQ(alone.slices[i].values, fromFolder.slices[i].values);
}

TEST(FindScans, PutsDamagedFilesWithTheirSeriesAndUnreadableOnesApart) {
    TempDir tmp;
    const fs::path root = tmp / "archive";
    writeSeries(root / "s", 6, "s");
    const fs::path cutPixels = filesIn(root / "s").back();
    fs::resize_file(cutPixels, fs::file_size(cutPixels) - 100);  // its series UID still read
    // A copy cut inside its header, alone in a folder: its series cannot be told.
    fs::create_directories(root / "junk");
    fs::copy_file(filesIn(root / "s").front(), root / "junk" / "cut.dcm");
    fs::resize_file(root / "junk" / "cut.dcm", 300);

    const std::vector<FoundScan> found = palp::volume::findScans(root);
    ASSERT_EQ(found.size(), 2u);
    EXPECT_EQ(found[0].folder, root / "junk");
    EXPECT_TRUE(found[0].unreadable);
    EXPECT_EQ(found[0].seriesUid, "");
    EXPECT_EQ(found[0].imageCount, 0);
    EXPECT_EQ(found[1].folder, root / "s");
    EXPECT_FALSE(found[1].unreadable);
    EXPECT_EQ(found[1].imageCount, 5);     // the damaged file is not scanned as an image...
    EXPECT_EQ(found[1].files.size(), 6u);  // ...but goes with its series
    // load() refuses both, naming the file.
    palp::volume::LoadOptions opt;
    opt.seriesUid = found[1].seriesUid;
    palp::test::expectThrowWith<palp::FormatError>([&] { palp::volume::load(found[1].files, opt); },
                                                   {cutPixels.string(), "truncated"});
    palp::test::expectThrowWith<palp::FormatError>(
        [&] { palp::volume::load(found[0].files, {}); },
        {(root / "junk" / "cut.dcm").string(), "expected a complete DICOM header"});
}

TEST(FindScans, RefusesAFolderThatIsNotThere) {
    TempDir tmp;
    palp::test::expectThrowWith<palp::IoError>([&] { palp::volume::findScans(tmp / "nope"); },
                                               {"nope: expected a folder of scans, found nothing"});
    std::ofstream(tmp / "file") << "x";
    palp::test::expectThrowWith<palp::IoError>([&] { palp::volume::findScans(tmp / "file"); },
                                               {"file: expected a folder of scans, found a file"});
}

}  // namespace
