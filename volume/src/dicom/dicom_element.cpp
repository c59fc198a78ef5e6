#include "dicom/dicom_element.h"

#include <algorithm>
#include <cstdio>
#include <cstring>

#include "dicom/dicom_header.h"

namespace palp::volume::dicom {

namespace {

/// Bytes per value of the binary VR @p vr; 0 for any other VR.
std::size_t binarySize(gdcm::VR vr) {
    switch (static_cast<gdcm::VR::VRType>(vr)) {
        case gdcm::VR::US:
        case gdcm::VR::SS:
            return 2;
        case gdcm::VR::UL:
        case gdcm::VR::SL:
        case gdcm::VR::FL:
            return 4;
        case gdcm::VR::FD:
            return 8;
        default:
            return 0;
    }
}

bool isNumberText(gdcm::VR vr) { return vr == gdcm::VR::IS || vr == gdcm::VR::DS; }

template <typename T>
double load(const char* p) {
    T v;
    std::memcpy(&v, p, sizeof(T));  // little endian, as palp reads DICOM
    return static_cast<double>(v);
}

ElementNumbers binary(const std::string& raw, gdcm::VR vr) {
    ElementNumbers out;
    const std::size_t size = binarySize(vr);
    if (raw.empty() || raw.size() % size != 0) {
        out.problem = std::to_string(raw.size()) + " bytes, not a whole number of " +
                      gdcm::VR::GetVRString(vr) + " values";
        return out;
    }
    for (std::size_t at = 0; at < raw.size(); at += size) {
        const char* p = raw.data() + at;
        switch (static_cast<gdcm::VR::VRType>(vr)) {
            case gdcm::VR::US:
                out.values.push_back(load<std::uint16_t>(p));
                break;
            case gdcm::VR::SS:
                out.values.push_back(load<std::int16_t>(p));
                break;
            case gdcm::VR::UL:
                out.values.push_back(load<std::uint32_t>(p));
                break;
            case gdcm::VR::SL:
                out.values.push_back(load<std::int32_t>(p));
                break;
            case gdcm::VR::FL:
                out.values.push_back(load<float>(p));
                break;
            default:
                out.values.push_back(load<double>(p));
                break;
        }
    }
    return out;
}

ElementNumbers text(const std::string& raw, gdcm::VR vr) {
    ElementNumbers out;
    const std::string t = trim(raw);
    if (const auto v = parseNumbers(t)) {
        out.values = *v;
    } else {
        // Appended piece by piece: GCC 12 warns falsely (-Wrestrict) of "'" + std::string.
        out.problem.reserve(t.size() + 16);
        out.problem.append(1, '\'').append(t).append("', not ");
        out.problem.append(gdcm::VR::GetVRString(vr)).append(" text");
    }
    return out;
}

}  // namespace

std::optional<gdcm::Tag> privateTag(const gdcm::DataSet& ds, std::uint16_t group,
                                    std::uint8_t elementByte, const std::string& creator) {
    bool anyCreator = false;
    for (std::uint16_t block = 0x10; block <= 0xFF; ++block) {
        const gdcm::Tag t(group, block);
        if (!ds.FindDataElement(t)) continue;
        anyCreator = true;
        if (trim(rawBytes(ds, t)) == creator)
            return gdcm::Tag(group, static_cast<std::uint16_t>(block << 8 | elementByte));
    }
    if (anyCreator) return std::nullopt;
    return gdcm::Tag(group, static_cast<std::uint16_t>(0x10 << 8 | elementByte));
}

ElementNumbers numbersOf(const gdcm::DataElement& de, gdcm::VR knownVr) {
    const gdcm::ByteValue* bv = de.GetByteValue();
    const std::string raw =
        bv && bv->GetPointer() ? std::string(bv->GetPointer(), bv->GetLength()) : std::string();
    if (raw.empty()) return {{}, "an empty value"};
    const gdcm::VR declared = de.GetVR();
    const bool known = declared != gdcm::VR::INVALID && declared != gdcm::VR::UN;
    if (known) {
        if (binarySize(declared) > 0) return binary(raw, declared);
        if (isNumberText(declared)) return text(raw, declared);
        return {{}, std::string("VR ") + gdcm::VR::GetVRString(declared) + ", not a number"};
    }
    // No VR in the file: the element's own VR decides. A binary VR's single value is read as
    // such whatever its bytes (33 00 is 51, not "3"); a longer value that reads as decimal text
    // is a converter's rewrite as IS or DS; else the binary values.
    const std::size_t size = binarySize(knownVr);
    if (size > 0) {
        if (raw.size() == size) return binary(raw, knownVr);
        ElementNumbers asText = text(raw, gdcm::VR::IS);
        if (!asText.values.empty()) return asText;
        if (raw.size() % size == 0) return binary(raw, knownVr);
        return {{},
                std::to_string(raw.size()) + " bytes, neither " + gdcm::VR::GetVRString(knownVr) +
                    " values nor decimal text"};
    }
    return text(raw, knownVr);
}

ElementNumbers numbersOf(const gdcm::DataSet& ds, const gdcm::Tag& tag, gdcm::VR knownVr) {
    if (!ds.FindDataElement(tag)) return {{}, "absent"};
    return numbersOf(ds.GetDataElement(tag), knownVr);
}

std::string rawBytes(const gdcm::DataSet& ds, const gdcm::Tag& tag) {
    if (!ds.FindDataElement(tag)) return {};
    const gdcm::ByteValue* bv = ds.GetDataElement(tag).GetByteValue();
    if (!bv || !bv->GetPointer()) return {};
    return std::string(bv->GetPointer(), bv->GetLength());
}

std::string tagText(const gdcm::Tag& tag) {
    char buf[16];
    std::snprintf(buf, sizeof buf, "(%04x,%04x)", tag.GetGroup(), tag.GetElement());
    return buf;
}

}  // namespace palp::volume::dicom
