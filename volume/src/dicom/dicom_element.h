#pragma once
// Reading one element's value by its value representation (internal). An explicit-VR file says
// how each value is stored; an implicit-VR file does not, and a converter may have turned a
// private element's VR into UN. A binary value read as text goes wrong silently: Siemens stores
// Number Of Images In Mosaic (0019,100A) as US, so 51 slices are the bytes 33 00, which read as
// text are "3". Every private or binary element palp reads therefore goes through here, with the
// VR palp knows the element has.
#include <gdcmDataSet.h>
#include <gdcmTag.h>
#include <gdcmVR.h>

#include <cstdint>
#include <optional>
#include <string>
#include <vector>

namespace palp::volume::dicom {

/// The tag of the private element @p elementByte of the block that @p creator reserves in
/// @p group of @p ds: (group, block << 8 | elementByte), the block being the element of the
/// Private Creator (group, 0x0010-0x00FF) whose value is @p creator. A data set without any
/// creator in the group gives block 0x10 (some anonymisers drop creators but keep the elements,
/// as dcm2niix accepts); nullopt when the group's creators are all others.
std::optional<gdcm::Tag> privateTag(const gdcm::DataSet& ds, std::uint16_t group,
                                    std::uint8_t elementByte, const std::string& creator);

/// What numbersOf() read.
struct ElementNumbers {
    std::vector<double> values;  ///< empty when the value could not be read
    std::string problem;         ///< why not, for messages ("3 bytes, neither US nor text")
};

/// The numbers held by @p de, read by its value representation: the VR the file declares, or,
/// where it declares none (implicit VR) or UN, @p knownVr (the VR the standard or the vendor
/// gives the element). Binary VRs (US, SS, UL, SL, FL, FD) are read little endian, as palp reads
/// DICOM; text VRs (IS, DS) are parsed as backslash-separated decimals. Without a declared VR, a
/// value of exactly one binary @p knownVr value is read as that (bytes 33 00 are US 51, although
/// 33 is the digit '3'); a longer one that parses as decimal text as text (a converter's rewrite
/// as IS); else as binary values when the length allows.
ElementNumbers numbersOf(const gdcm::DataElement& de, gdcm::VR knownVr);

/// numbersOf() of the element @p tag in @p ds; a problem "absent" when it is not there.
ElementNumbers numbersOf(const gdcm::DataSet& ds, const gdcm::Tag& tag, gdcm::VR knownVr);

/// The raw bytes of @p tag in @p ds (binary values such as a CSA header); empty when absent.
std::string rawBytes(const gdcm::DataSet& ds, const gdcm::Tag& tag);

/// "(0019,100a)" for messages.
std::string tagText(const gdcm::Tag& tag);

}  // namespace palp::volume::dicom
