// libFuzzer target: palp's Siemens MOSAIC logic. The input is
//   byte 0: columns (1-64), byte 1: rows (1-64), bytes 2-3: Number Of Images In Mosaic
//   (0019,100A) as stored (US), byte 4: flags (creators present or wrong, the count as text,
//   slice spacing given, orientation choice), then the bytes of the CSA image header (0029,1010).
// The CSA parser (csaItems) also reads the whole input as a header. mosaicLayout reads the
// private tags and the CSA header; what it accepts must tile the image, and mosaicSlices must
// cut a known mosaic into slices holding exactly the tiles' pixels at finite positions.
// Any palp::Error is an accepted outcome; crashes, sanitizer reports, leaks and other
// exceptions are findings.
#include <gdcmDataElement.h>
#include <gdcmDataSet.h>

#include <cmath>
#include <cstddef>
#include <cstdint>
#include <string>
#include <vector>

#include "dicom/dicom_header.h"
#include "dicom/dicom_mosaic.h"
#include "palp/base/error.h"

namespace {

using namespace palp::volume::dicom;

void put(gdcm::DataSet& ds, std::uint16_t g, std::uint16_t e, gdcm::VR vr, const std::string& v) {
    gdcm::DataElement de(gdcm::Tag(g, e));
    de.SetVR(vr);
    de.SetByteValue(v.data(), static_cast<std::uint32_t>(v.size()));
    ds.Replace(de);
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
    const std::string bytes(reinterpret_cast<const char*>(data), size);
    for (const char* name : {"NumberOfImagesInMosaic", "SliceNormalVector", ""}) {
        for (const std::string& item : csaItems(bytes, name)) {
            if (item.size() > bytes.size()) __builtin_trap();
        }
    }
    if (size < 5) return 0;
    const int cols = 1 + data[0] % 64, rows = 1 + data[1] % 64;
    const std::uint8_t flags = data[4];
    const std::string csa = bytes.substr(5);

    Header h;
    h.path = "fuzz.dcm";
    h.values[kColumns] = std::to_string(cols);
    h.values[kRows] = std::to_string(rows);
    h.values[kImageType] = "ORIGINAL\\PRIMARY\\M\\ND\\MOSAIC";
    h.values[kImagePosition] = "-100\\-80.5\\20";
    h.values[kImageOrientation] = (flags & 0x40) ? "0.6\\0.8\\0\\0\\0\\1" : "1\\0\\0\\0\\1\\0";
    h.values[kPixelSpacing] = "2.5\\2";
    if (flags & 0x10) h.values[kSpacingBetweenSlices] = "3.3";
    if (flags & 0x20) h.values[kSliceThickness] = (flags & 0x80) ? "-1" : "3";

    gdcm::DataSet ds;
    put(ds, 0x0019, 0x0010, gdcm::VR::LO, (flags & 1) ? "SIEMENS MR HEADER " : "OTHER");
    if (flags & 2) {
        put(ds, 0x0019, 0x100a, gdcm::VR::US, bytes.substr(2, 2));
    } else {
        put(ds, 0x0019, 0x100a, gdcm::VR::IS, std::to_string(data[2] % 40));
    }
    if (!(flags & 4)) put(ds, 0x0029, 0x0010, gdcm::VR::LO, "SIEMENS CSA HEADER");
    if (!(flags & 8)) put(ds, 0x0029, 0x1010, gdcm::VR::OB, csa);

    MosaicLayout m;
    try {
        m = mosaicLayout(h, ds);
    } catch (const palp::Error&) {
        return 0;
    }
    if (m.slices < 1 || m.grid < 1 || m.grid * m.grid < m.slices ||
        (m.grid - 1) * (m.grid - 1) >= m.slices || m.tileColumns * m.grid != cols ||
        m.tileRows * m.grid != rows || !(std::abs(m.normal.norm() - 1) < 1e-6)) {
        __builtin_trap();
    }
    std::vector<float> mosaic(static_cast<std::size_t>(cols) * static_cast<std::size_t>(rows));
    for (std::size_t i = 0; i < mosaic.size(); ++i) mosaic[i] = static_cast<float>(i);
    try {
        const std::vector<palp::volume::Slice> slices = mosaicSlices(h, m, mosaic);
        if (slices.size() != static_cast<std::size_t>(m.slices)) __builtin_trap();
        for (int k = 0; k < m.slices; ++k) {
            const auto& s = slices[static_cast<std::size_t>(k)];
            if (!s.position.allFinite() || s.cols != m.tileColumns || s.rows != m.tileRows)
                __builtin_trap();
            const int c0 = (k % m.grid) * m.tileColumns, r0 = (k / m.grid) * m.tileRows;
            for (int r = 0; r < s.rows; ++r) {
                for (int c = 0; c < s.cols; ++c) {
                    const float expected = static_cast<float>((r0 + r) * cols + c0 + c);
                    if (s.values[static_cast<std::size_t>(r * s.cols + c)] != expected)
                        __builtin_trap();
                }
            }
        }
    } catch (const palp::Error&) {
    }
    return 0;
}
