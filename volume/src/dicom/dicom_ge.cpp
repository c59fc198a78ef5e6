#include "dicom/dicom_ge.h"

#include <gdcmReader.h>

#include <cctype>
#include <cstdint>
#include <cstring>
#include <set>

#include "dicom/dicom_element.h"

namespace palp::volume::dicom {

namespace {

const gdcm::Tag kManufacturerTag(0x0008, 0x0070);
const gdcm::Tag kPhaseReordering(0x0018, 0x9034);
const gdcm::Tag kUserDefineDataGE(0x0043, 0x102a);

std::int32_t int16At(const std::string& b, std::size_t at) {
    return static_cast<std::int16_t>(static_cast<std::uint16_t>(
        static_cast<unsigned char>(b[at]) | static_cast<unsigned char>(b[at + 1]) << 8));
}

std::string upper(std::string s) {
    for (char& c : s) c = static_cast<char>(std::toupper(static_cast<unsigned char>(c)));
    return s;
}

}  // namespace

std::string gePhaseEncodingPolarity(const gdcm::DataSet& ds) {
    const std::string maker = upper(rawBytes(ds, kManufacturerTag));
    if (maker.rfind("GE", 0) != 0) return "";
    const std::string reordering = upper(rawBytes(ds, kPhaseReordering));
    if (reordering.size() >= 2 && reordering[0] == 'L') return "Flipped";
    if (reordering.size() >= 2 && reordering[0] == 'R') return "Unflipped";
    const std::string b = rawBytes(ds, kUserDefineDataGE);
    if (b.size() < 916) return "";
    const std::size_t offset = static_cast<std::size_t>(int16At(b, 24)) & 0xffffu;
    if (b.size() < offset + 916) return "";
    float version = 0;
    std::memcpy(&version, b.data() + offset, sizeof version);
    if (!(version >= 5.0f && version <= 40.0f)) return "";
    std::size_t hdr = offset, viewOrderAt = 0x0394;
    if (version >= 25.002f) {
        hdr += 0x004c;
        viewOrderAt -= 0x008c;
    }
    if (hdr + viewOrderAt + 2 > b.size()) return "";
    if ((int16At(b, hdr + 0x3a) & 0x800) == 0) return "";  // not EPI
    bool flipped = (int16At(b, hdr + 0x30) & 0x0004) != 0;
    if (int16At(b, hdr + viewOrderAt) == 2) flipped = !flipped;  // bottom-up view order
    return flipped ? "Flipped" : "Unflipped";
}

std::string gePhaseEncodingPolarity(const std::filesystem::path& file) {
    gdcm::Reader reader;
    reader.SetFileName(file.c_str());
    const std::set<gdcm::Tag> tags{kManufacturerTag, kPhaseReordering, kUserDefineDataGE};
    if (!reader.ReadSelectedTags(tags)) return "";
    return gePhaseEncodingPolarity(reader.GetFile().GetDataSet());
}

}  // namespace palp::volume::dicom
