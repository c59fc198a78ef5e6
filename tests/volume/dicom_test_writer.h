#pragma once
/// @file
/// One single-frame DICOM image written through GDCM, as the DICOM tests make their series
/// (stored pixels of any 16-bit layout, the caller's own elements added: time keys, private
/// tags, CSA headers): the GDCM writing that test_dicom_signed_mr, test_dicom_time_order and
/// test_dicom_mosaic each repeated. palp::volume::writeDicomSeries() writes whole series of
/// uint16 storage; this writes what a test needs that it does not.

#include <gdcmImageWriter.h>
#include <gdcmMediaStorage.h>
#include <gdcmTrace.h>
#include <gdcmUIDGenerator.h>
#include <gtest/gtest.h>

#include <array>
#include <cstdint>
#include <filesystem>
#include <functional>
#include <string>
#include <vector>

namespace palp::test {

/// Sets @p ds's element (g, e) to the text @p v with VR @p vr, padded to an even length (NUL
/// for UI, space otherwise).
inline void setText(gdcm::DataSet& ds, std::uint16_t g, std::uint16_t e, gdcm::VR vr,
                    std::string v) {
    if (v.size() % 2) v.push_back(vr == gdcm::VR::UI ? '\0' : ' ');
    gdcm::DataElement de(gdcm::Tag(g, e));
    de.SetVR(vr);
    de.SetByteValue(v.data(), static_cast<std::uint32_t>(v.size()));
    ds.Replace(de);
}

/// Sets @p ds's element @p tag to @p bytes (binary, little endian as written) with VR @p vr.
inline void setBytes(gdcm::DataSet& ds, const gdcm::Tag& tag, gdcm::VR vr,
                     const std::string& bytes) {
    gdcm::DataElement de(tag);
    de.SetVR(vr);
    de.SetByteValue(bytes.data(), static_cast<std::uint32_t>(bytes.size()));
    ds.Replace(de);
}

/// Sets @p ds's element (g, e) to the doubles @p v (VR FD).
inline void setDoubles(gdcm::DataSet& ds, std::uint16_t g, std::uint16_t e,
                       const std::vector<double>& v) {
    gdcm::DataElement de(gdcm::Tag(g, e));
    de.SetVR(gdcm::VR::FD);
    de.SetByteValue(reinterpret_cast<const char*>(v.data()),
                    static_cast<std::uint32_t>(v.size() * sizeof(double)));
    ds.Replace(de);
}

/// One image: its pixels, their storage and its plane.
struct DicomImage {
    int cols = 0, rows = 0;
    /// Stored 16-bit words, row-major, cols x rows (an int16 value's bits for signed storage).
    std::vector<std::uint16_t> pixels;
    gdcm::PixelFormat format = gdcm::PixelFormat(gdcm::PixelFormat::INT16);
    std::array<double, 6> cosines{1, 0, 0, 0, 1, 0};  ///< Image Orientation: row, then column
    std::array<double, 3> spacingMm{1, 1, 1};   ///< column step, row step, spacing between slices
    std::array<double, 3> positionMm{0, 0, 0};  ///< Image Position (Patient)
    gdcm::TransferSyntax::TSType syntax = gdcm::TransferSyntax::ExplicitVRLittleEndian;
    std::string modality = "MR";  ///< also chooses the SOP class: CT or MR Image Storage
};

/// @p values as stored words (the bits of each int16).
template <typename T>
std::vector<std::uint16_t> storedWords(const std::vector<T>& values) {
    std::vector<std::uint16_t> words;
    words.reserve(values.size());
    for (const T v : values) words.push_back(static_cast<std::uint16_t>(v));
    return words;
}

/// Writes @p image to @p file: its plane (orientation, spacing, position), its pixels as
/// MONOCHROME2 of @p image.format, SOP Class and a fresh SOP Instance UID, Modality; then
/// @p elements adds the test's own elements (series UIDs, time keys, private tags), which replace
/// any of these. Fails the test (ASSERT) when GDCM cannot write it.
inline void writeDicomImage(const std::filesystem::path& file, const DicomImage& image,
                            const std::function<void(gdcm::DataSet&)>& elements = {}) {
    gdcm::Trace::WarningOff();  // GDCM's writer warns of the Photometric Interpretation it sets
    gdcm::ImageWriter writer;
    gdcm::Image& im = writer.GetImage();
    im.SetNumberOfDimensions(2);
    im.SetDimension(0, static_cast<unsigned>(image.cols));
    im.SetDimension(1, static_cast<unsigned>(image.rows));
    im.SetPixelFormat(image.format);
    im.SetPhotometricInterpretation(gdcm::PhotometricInterpretation::MONOCHROME2);
    im.SetDirectionCosines(image.cosines.data());
    im.SetSpacing(image.spacingMm.data());
    im.SetSpacing(2, image.spacingMm[2]);
    im.SetOrigin(image.positionMm.data());
    im.SetOrigin(2, image.positionMm[2]);  // a 2D gdcm::Image keeps two components of the array
    gdcm::DataElement pd(gdcm::Tag(0x7fe0, 0x0010));
    pd.SetByteValue(reinterpret_cast<const char*>(image.pixels.data()),
                    static_cast<std::uint32_t>(image.pixels.size() * 2));
    im.SetDataElement(pd);
    im.SetTransferSyntax(image.syntax);
    gdcm::File& f = writer.GetFile();
    f.GetHeader().SetDataSetTransferSyntax(image.syntax);
    gdcm::DataSet& ds = f.GetDataSet();
    setText(ds, 0x0008, 0x0016, gdcm::VR::UI,
            gdcm::MediaStorage::GetMSString(image.modality == "CT"
                                                ? gdcm::MediaStorage::CTImageStorage
                                                : gdcm::MediaStorage::MRImageStorage));
    gdcm::UIDGenerator gen;
    setText(ds, 0x0008, 0x0018, gdcm::VR::UI, gen.Generate());
    setText(ds, 0x0008, 0x0060, gdcm::VR::CS, image.modality);
    if (elements) elements(ds);
    writer.SetFileName(file.c_str());
    ASSERT_TRUE(writer.Write()) << file;
}

}  // namespace palp::test
