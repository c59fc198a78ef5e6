// GE's phase-encoding polarity (issue 37 item 3). dcm2niix reads it from Rectilinear Phase
// Encode Reordering (0018,9034) or GE's user data block (0043,102A) and writes it to its JSON
// sidecar ("PhaseEncodingPolarityGE") without changing a pixel; palp records it the same way
// (VolumeInfo::phaseEncodingPolarityGE, metadata "palp:phase_encoding_polarity_ge", `palp info`)
// and keeps the pixels as stored. Synthetic series carry the block laid out as dcm2niix reads
// it; the shared GE EPI gives what dcm2niix's sidecar says.
#include <gdcmReader.h>
#include <gdcmWriter.h>
#include <gtest/gtest.h>

#include <cstdint>
#include <cstring>
#include <filesystem>
#include <string>
#include <vector>

#include "dicom_test_writer.h"
#include "palp/volume/dicom.h"
#include "palp/volume/load.h"
#include "test_support.h"

namespace {

namespace fs = std::filesystem;
namespace pv = palp::volume;
using palp::test::setBytes;
using palp::test::setText;
using palp::test::TempDir;

/// GE's user data block (0043,102A): header at byte 100 of version @p version, the EPI flag
/// set when @p epi, the polarity bit when @p polarityBit, view order @p viewOrder.
std::string userData(float version, bool epi, bool polarityBit, std::int16_t viewOrder) {
    std::string b(1200, '\0');
    const auto put16 = [&](std::size_t at, std::int16_t v) { std::memcpy(&b[at], &v, 2); };
    const std::size_t offset = 100;
    put16(24, static_cast<std::int16_t>(offset));
    std::memcpy(&b[offset], &version, sizeof version);
    std::size_t hdr = offset, viewOrderAt = 0x0394;
    if (version >= 25.002f) {
        hdr += 0x004c;
        viewOrderAt -= 0x008c;
    }
    put16(hdr + 0x3a, epi ? 0x0800 : 0);
    put16(hdr + 0x30, polarityBit ? 0x0004 : 0);
    put16(hdr + viewOrderAt, viewOrder);
    return b;
}

/// A 3-slice MR series in @p dir, every file with Manufacturer @p maker, the block @p block
/// (when not empty) and Rectilinear Phase Encode Reordering @p reordering (when not empty).
void writeSeries(const fs::path& dir, const std::string& maker, const std::string& block,
                 const std::string& reordering) {
    pv::SliceStack st;
    st.info.modality = "MR";
    for (int k = 0; k < 3; ++k) {
        pv::Slice s;
        s.cols = 6;
        s.rows = 5;
        s.colStep = {2e-3, 0, 0};
        s.rowStep = {0, 2e-3, 0};
        s.position = {0, 0, 3e-3 * k};
        for (int i = 0; i < s.cols * s.rows; ++i)
            s.values.push_back(static_cast<float>(10 + i + 100 * k));
        st.slices.push_back(s);
    }
    pv::DicomWriteOptions wo;
    wo.modality = "MR";
    wo.rescaleIntercept = 0;
    const fs::path plain = dir.string() + ".plain";
    pv::writeDicomSeries(st, plain, wo);
    fs::create_directories(dir);
    for (const auto& e : fs::directory_iterator(plain)) {
        gdcm::Reader reader;
        reader.SetFileName(e.path().c_str());
        ASSERT_TRUE(reader.Read());
        gdcm::DataSet& ds = reader.GetFile().GetDataSet();
        setText(ds, 0x0008, 0x0070, gdcm::VR::LO, maker);
        if (!block.empty()) {
            setText(ds, 0x0043, 0x0010, gdcm::VR::LO, "GEMS_PARM_01");
            setBytes(ds, gdcm::Tag(0x0043, 0x102a), gdcm::VR::OB, block);
        }
        if (!reordering.empty()) setText(ds, 0x0018, 0x9034, gdcm::VR::CS, reordering);
        gdcm::Writer writer;
        writer.SetFile(reader.GetFile());
        writer.SetFileName((dir / e.path().filename()).c_str());
        ASSERT_TRUE(writer.Write());
    }
}

/// The polarity palp records for the series, with its grid checked equal to the series' grid
/// without any polarity element (no pixel changed).
std::string polarityOf(const TempDir& tmp, const std::string& name, const std::string& maker,
                       const std::string& block, const std::string& reordering = "") {
    const fs::path dir = tmp / name;
    writeSeries(dir, maker, block, reordering);
    const pv::Volume v = pv::load({dir});
    const pv::Volume plain = pv::load({dir.string() + ".plain"});
    EXPECT_EQ(v.grid->activeVoxelCount(), plain.grid->activeVoxelCount()) << name;
    for (auto it = plain.grid->cbeginValueOn(); it; ++it)
        EXPECT_EQ(v.grid->tree().getValue(it.getCoord()), *it) << name;
    return v.info.phaseEncodingPolarityGE;
}

TEST(DicomGePolarity, ReadAsDcm2niixReadsItAndPixelsKept) {
    TempDir tmp;
    const std::string ge = "GE MEDICAL SYSTEMS";
    EXPECT_EQ(polarityOf(tmp, "v24flip", ge, userData(24.0f, true, true, 0)), "Flipped");
    EXPECT_EQ(polarityOf(tmp, "v24plain", ge, userData(24.0f, true, false, 0)), "Unflipped");
    // From version 25.002 the fields move; a bottom-up view order inverts the bit.
    EXPECT_EQ(polarityOf(tmp, "v27up", ge, userData(27.0f, true, false, 2)), "Flipped");
    EXPECT_EQ(polarityOf(tmp, "v27down", ge, userData(27.0f, true, true, 2)), "Unflipped");
    // (0018,9034) goes first.
    EXPECT_EQ(polarityOf(tmp, "reorder", ge, userData(24.0f, true, true, 0), "REVERSE_LINEAR"),
              "Unflipped");
    EXPECT_EQ(polarityOf(tmp, "linear", ge, "", "LINEAR"), "Flipped");
    // Not EPI, not GE, a version out of range, or nothing said: no polarity.
    EXPECT_EQ(polarityOf(tmp, "notepi", ge, userData(24.0f, false, true, 0)), "");
    EXPECT_EQ(polarityOf(tmp, "siemens", "SIEMENS", userData(24.0f, true, true, 0)), "");
    EXPECT_EQ(polarityOf(tmp, "badversion", ge, userData(99.0f, true, true, 0)), "");
    EXPECT_EQ(polarityOf(tmp, "none", ge, ""), "");

    // Kept in the .vdb and shown by `palp info`.
    const pv::Volume v = pv::load({tmp / "v24flip"});
    pv::save(v, tmp / "flip.vdb");
    EXPECT_EQ(pv::loadVdb(tmp / "flip.vdb").info.phaseEncodingPolarityGE, "Flipped");
    const auto r = palp::test::runCommand("'" + palp::test::palpTool().string() +
                                          "' info --json '" + (tmp / "flip.vdb").string() + "'");
    ASSERT_EQ(r.exitCode, 0) << r.output;
    EXPECT_NE(r.output.find("\"phase_encoding_polarity_ge\": \"Flipped\""), std::string::npos)
        << r.output;
}

TEST(DicomGePolarity, TheSharedGeEpiSaysWhatDcm2niixSidecarSays) {
    // reference-dcm2niix/DCM2NIIX_regression_test_4.json: "PhaseEncodingPolarityGE":
    // "Unflipped"; its pixels equal palp's (DicomRead.FourDimensionalSeriesMatchesDcm2niix).
    PALP_REQUIRE_DATA(dir, "mr-ge-epi-4d");
    pv::ReadOptions opt;
    opt.timePoint = 0;
    EXPECT_EQ(pv::readDicom({dir / "dicom"}, opt).info.phaseEncodingPolarityGE, "Unflipped");
}

}  // namespace
