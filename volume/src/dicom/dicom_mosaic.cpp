#include "dicom/dicom_mosaic.h"

#include <gdcmImageReader.h>
#include <gdcmReader.h>

#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstring>
#include <set>

#include "dicom/dicom_element.h"
#include "dicom/dicom_pixels.h"
#include "palp/base/error.h"

namespace palp::volume::dicom {

namespace {

std::int32_t i32(const std::string& b, std::size_t at) {
    std::int32_t v = 0;
    std::memcpy(&v, b.data() + at, 4);
    return v;
}

/// Number Of Images In Mosaic (0019,xx0A) of the "SIEMENS MR HEADER" block, read by its VR (US
/// in Siemens files: bytes 33 00 are 51, not the text "3"; see numbersOf); 0 when absent or
/// unusable, and then @p problem says what a present value held.
int imagesInMosaicTag(const gdcm::DataSet& ds, std::string& problem) {
    const auto tag = privateTag(ds, 0x0019, 0x0A, "SIEMENS MR HEADER");
    if (!tag || !ds.FindDataElement(*tag)) return 0;
    const ElementNumbers n = numbersOf(ds, *tag, gdcm::VR::US);
    if (n.values.size() == 1 && n.values[0] >= 1 && n.values[0] <= 10000 &&
        n.values[0] == std::floor(n.values[0])) {
        return static_cast<int>(n.values[0]);
    }
    std::string found = n.problem;
    if (found.empty()) {
        for (const double v : n.values) {
            char buf[32];
            std::snprintf(buf, sizeof buf, "%.10g", v);
            found += (found.empty() ? "" : "\\") + std::string(buf);
        }
        found = "'" + found + "'";
    }
    problem = "; Number Of Images In Mosaic " + tagText(*tag) +
              " held no count of 1 to 10000 but " + found;
    return 0;
}

/// The CSA Image Header (0029,xx10) of the "SIEMENS CSA HEADER" block (binary); empty when
/// absent.
std::string csaImageHeader(const gdcm::DataSet& ds) {
    const auto tag = privateTag(ds, 0x0029, 0x10, "SIEMENS CSA HEADER");
    return tag ? rawBytes(ds, *tag) : std::string();
}

}  // namespace

std::vector<std::string> csaItems(const std::string& bytes, const std::string& name) {
    const bool sv10 = bytes.size() >= 4 && bytes.compare(0, 4, "SV10") == 0;
    std::size_t at = sv10 ? 8 : 0;
    if (at + 8 > bytes.size()) return {};
    const std::int32_t tags = i32(bytes, at);
    if (tags < 1 || tags > 1000) return {};
    at += 8;  // tag count, then a word that is 77
    for (std::int32_t t = 0; t < tags; ++t) {
        if (at + 84 > bytes.size()) return {};
        const std::string tagName(bytes.data() + at, strnlen(bytes.data() + at, 64));
        const std::int32_t items = i32(bytes, at + 76);
        const std::int32_t tagWord = i32(bytes, at + 80);
        at += 84;
        if (items < 0 || items > 10000) return {};
        std::vector<std::string> values;
        for (std::int32_t i = 0; i < items; ++i) {
            if (at + 16 > bytes.size()) return {};
            // SV10 gives the item's length in its second word; CSA1 as the first word less the
            // tag's own word (nibabel's reading of the older layout).
            const std::int64_t length =
                sv10 ? i32(bytes, at + 4) : std::int64_t{i32(bytes, at)} - tagWord;
            at += 16;
            if (length < 0 || at + static_cast<std::size_t>(length) > bytes.size()) return {};
            values.push_back(trim(bytes.substr(at, static_cast<std::size_t>(length))));
            at += (static_cast<std::size_t>(length) + 3) / 4 * 4;
        }
        if (tagName == name) return values;
    }
    return {};
}

bool isMosaic(const Header& h) {
    const std::string type = h.text(kImageType);
    std::size_t start = 0;
    while (start <= type.size()) {
        const std::size_t end = std::min(type.find('\\', start), type.size());
        if (trim(type.substr(start, end - start)) == "MOSAIC") return true;
        start = end + 1;
    }
    return false;
}

MosaicLayout mosaicLayout(const Header& h, const gdcm::DataSet& ds) {
    const std::string file = h.path.string();
    const std::string csa = csaImageHeader(ds);
    MosaicLayout m;
    std::string problem;
    m.slices = imagesInMosaicTag(ds, problem);
    const auto items = csaItems(csa, "NumberOfImagesInMosaic");
    const auto csaCount = items.empty() ? std::nullopt : parseNumber(items.front());
    if (csaCount && *csaCount >= 1 && *csaCount <= 10000) {
        const int n = static_cast<int>(std::lround(*csaCount));
        if (m.slices >= 1 && m.slices != n) {
            throw FormatError(file +
                              ": expected Number Of Images In Mosaic (0019,100A) and the CSA "
                              "image header's NumberOfImagesInMosaic to agree, found " +
                              std::to_string(m.slices) + " and " + std::to_string(n));
        }
        m.slices = n;
    }
    if (m.slices < 1) {
        throw FormatError(file +
                          ": expected Number Of Images In Mosaic (0019,100A) or the CSA image "
                          "header's NumberOfImagesInMosaic for an Image Type MOSAIC image, found "
                          "neither" +
                          problem);
    }
    m.grid = 1;
    while (m.grid * m.grid < m.slices) ++m.grid;
    const int cols = h.integer(kColumns, 0), rows = h.integer(kRows, 0);
    if (cols % m.grid != 0 || rows % m.grid != 0) {
        throw FormatError(file + ": expected a mosaic of " + std::to_string(m.grid) + "x" +
                          std::to_string(m.grid) + " equal tiles for " + std::to_string(m.slices) +
                          " slices, found " + std::to_string(cols) + "x" + std::to_string(rows) +
                          " pixels, which do not divide");
    }
    m.tileColumns = cols / m.grid;
    m.tileRows = rows / m.grid;

    const FileGeometry g = geometryOf(h);
    const Eigen::Vector3d planeNormal = g.rowCosine.cross(g.columnCosine).normalized();
    m.normal = planeNormal;
    const auto normalItems = csaItems(csa, "SliceNormalVector");
    if (normalItems.size() >= 3) {
        const auto x = parseNumber(normalItems[0]), y = parseNumber(normalItems[1]),
                   z = parseNumber(normalItems[2]);
        if (!x || !y || !z) {
            throw FormatError(file +
                              ": expected three numbers in the CSA image header's "
                              "SliceNormalVector, found '" +
                              normalItems[0] + "\\" + normalItems[1] + "\\" + normalItems[2] + "'");
        }
        const Eigen::Vector3d n(*x, *y, *z);
        // Within about half a degree of the plane's normal, either way round.
        if (!(std::abs(n.norm() - 1) < 0.01) || std::abs(std::abs(n.dot(planeNormal)) - 1) > 5e-5) {
            throw FormatError(file +
                              ": expected the CSA image header's SliceNormalVector normal to "
                              "the image plane of Image Orientation (Patient) (0020,0037), "
                              "found (" +
                              normalItems[0] + ", " + normalItems[1] + ", " + normalItems[2] + ")");
        }
        m.normal = n.normalized();
        m.normalFromCsa = true;
    }
    const auto spacing = h.number(kSpacingBetweenSlices);
    const auto thickness = h.number(kSliceThickness);
    m.spacingMm = spacing && *spacing > 0 ? *spacing : thickness && *thickness > 0 ? *thickness : 0;
    if (m.slices > 1 && !(m.spacingMm > 0 && m.spacingMm < 1e3)) {
        throw FormatError(file +
                          ": expected Spacing Between Slices (0018,0088) or Slice Thickness "
                          "(0018,0050) in (0, 1000) mm for the " +
                          std::to_string(m.slices) + " slices of a mosaic, found '" +
                          h.text(kSpacingBetweenSlices) + "' and '" + h.text(kSliceThickness) +
                          "'");
    }
    return m;
}

int mosaicSliceCount(const Header& h) {
    gdcm::Reader reader;
    reader.SetFileName(h.path.c_str());
    const std::set<gdcm::Tag> skip{kPixelData};
    if (!reader.ReadUpToTag(kPixelData, skip)) return 0;
    try {
        return mosaicLayout(h, reader.GetFile().GetDataSet()).slices;
    } catch (const FormatError&) {
        return 0;
    }
}

std::vector<Slice> mosaicSlices(const Header& h, const MosaicLayout& m,
                                const std::vector<float>& mosaic) {
    const std::string file = h.path.string();
    const int cols = h.integer(kColumns, 0), rows = h.integer(kRows, 0);
    if (mosaic.size() != static_cast<std::size_t>(cols) * static_cast<std::size_t>(rows) ||
        m.grid < 1 || m.slices > m.grid * m.grid || m.tileColumns * m.grid != cols ||
        m.tileRows * m.grid != rows) {
        throw FormatError(file + ": expected " + std::to_string(cols) + "x" + std::to_string(rows) +
                          " mosaic pixels in " + std::to_string(m.grid) + "x" +
                          std::to_string(m.grid) + " tiles for " + std::to_string(m.slices) +
                          " slices, found " + std::to_string(mosaic.size()) + " pixels");
    }
    const FileGeometry g = geometryOf(h);
    const Eigen::Vector3d colStepMm = g.rowCosine * g.columnSpacing;
    const Eigen::Vector3d rowStepMm = g.columnCosine * g.rowSpacing;
    // The mosaic's position is that of a tile-sized image centred on the whole mosaic.
    const Eigen::Vector3d firstMm = g.position + colStepMm * ((cols - m.tileColumns) / 2.0) +
                                    rowStepMm * ((rows - m.tileRows) / 2.0);
    std::vector<Slice> slices(static_cast<std::size_t>(m.slices));
    for (int k = 0; k < m.slices; ++k) {
        Slice& s = slices[static_cast<std::size_t>(k)];
        s.cols = m.tileColumns;
        s.rows = m.tileRows;
        s.position = (firstMm + m.normal * (m.spacingMm * k)) * 1e-3;
        s.colStep = colStepMm * 1e-3;
        s.rowStep = rowStepMm * 1e-3;
        s.source = file + " (mosaic slice " + std::to_string(k + 1) + ")";
        s.values.resize(static_cast<std::size_t>(m.tileColumns) *
                        static_cast<std::size_t>(m.tileRows));
        const int c0 = (k % m.grid) * m.tileColumns, r0 = (k / m.grid) * m.tileRows;
        for (int r = 0; r < m.tileRows; ++r) {
            const auto from = mosaic.begin() + static_cast<std::ptrdiff_t>(r0 + r) * cols + c0;
            std::copy(from, from + m.tileColumns,
                      s.values.begin() + static_cast<std::ptrdiff_t>(r) * m.tileColumns);
        }
    }
    return slices;
}

std::vector<Slice> readMosaic(const Header& h, std::array<std::int64_t, 3>& originalDims) {
    const std::string file = h.path.string();
    const double slope = checkedSlope(file, h.number(kRescaleSlope), h.text(kRescaleSlope));
    const double intercept = h.number(kRescaleIntercept).value_or(0.0);
    gdcm::ImageReader reader;
    std::vector<char> buffer;
    decodeFile(h, 1, reader, buffer);
    const MosaicLayout m = mosaicLayout(h, reader.GetFile().GetDataSet());
    const int cols = h.integer(kColumns, 0), rows = h.integer(kRows, 0);
    std::vector<float> mosaic;
    convertFrame(file, buffer.data(), reader.GetImage().GetPixelFormat(),
                 static_cast<std::size_t>(cols) * static_cast<std::size_t>(rows), slope, intercept,
                 mosaic);

    std::vector<Slice> slices = mosaicSlices(h, m, mosaic);
    originalDims = {m.tileColumns, m.tileRows, m.slices};
    return slices;
}

}  // namespace palp::volume::dicom
