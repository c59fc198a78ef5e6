// DICOM series reading through GDCM: a cheap header scan of every file (gdcm::Scanner), series
// and time point selection from those headers, then pixel decoding (gdcm::ImageReader, so every
// transfer syntax GDCM decodes works) of the chosen files only.
#include <gdcmImageReader.h>
#include <gdcmMediaStorage.h>
#include <gdcmReader.h>
#include <gdcmScanner.h>
#include <gdcmSequenceOfFragments.h>
#include <gdcmSequenceOfItems.h>
#include <gdcmTag.h>
#include <gdcmTrace.h>
#include <gdcmTransferSyntax.h>

#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <map>
#include <optional>
#include <set>
#include <sstream>
#include <string>
#include <vector>

#include "palp/base/error.h"
#include "palp/volume/dicom.h"

namespace palp::volume {

namespace fs = std::filesystem;

namespace {

// Tags read from every file. No patient-identifying tag is read.
const gdcm::Tag kSopClassUid(0x0008, 0x0016);
const gdcm::Tag kAcquisitionTime(0x0008, 0x0032);
const gdcm::Tag kContentTime(0x0008, 0x0033);
const gdcm::Tag kModality(0x0008, 0x0060);
const gdcm::Tag kSeriesDescription(0x0008, 0x103e);
const gdcm::Tag kGantryTilt(0x0018, 0x1120);
const gdcm::Tag kSeriesUid(0x0020, 0x000e);
const gdcm::Tag kAcquisitionNumber(0x0020, 0x0012);
const gdcm::Tag kInstanceNumber(0x0020, 0x0013);
const gdcm::Tag kImagePosition(0x0020, 0x0032);
const gdcm::Tag kImageOrientation(0x0020, 0x0037);
const gdcm::Tag kTemporalPosition(0x0020, 0x0100);
const gdcm::Tag kSamplesPerPixel(0x0028, 0x0002);
const gdcm::Tag kPhotometric(0x0028, 0x0004);
const gdcm::Tag kNumberOfFrames(0x0028, 0x0008);
const gdcm::Tag kRows(0x0028, 0x0010);
const gdcm::Tag kColumns(0x0028, 0x0011);
const gdcm::Tag kPixelSpacing(0x0028, 0x0030);
const gdcm::Tag kBitsAllocated(0x0028, 0x0100);
const gdcm::Tag kRescaleIntercept(0x0028, 0x1052);
const gdcm::Tag kRescaleSlope(0x0028, 0x1053);
const gdcm::Tag kPixelData(0x7fe0, 0x0010);

std::string trim(const std::string& s) {
    const auto notSpace = [](char c) {
        return c != ' ' && c != '\0' && c != '\t' && c != '\r' && c != '\n';
    };
    const auto b = std::find_if(s.begin(), s.end(), notSpace);
    const auto e = std::find_if(s.rbegin(), s.rend(), notSpace).base();
    return b < e ? std::string(b, e) : std::string();
}

/// Parses a backslash-separated list of decimal numbers; nullopt when any is not a finite number.
std::optional<std::vector<double>> parseNumbers(const std::string& text) {
    std::vector<double> out;
    std::string item;
    std::istringstream in(text);
    while (std::getline(in, item, '\\')) {
        const std::string t = trim(item);
        if (t.empty()) return std::nullopt;
        char* end = nullptr;
        const double v = std::strtod(t.c_str(), &end);
        if (end != t.c_str() + t.size() || !std::isfinite(v)) return std::nullopt;
        out.push_back(v);
    }
    if (out.empty()) return std::nullopt;
    return out;
}

std::optional<double> parseNumber(const std::string& text) {
    const auto v = parseNumbers(text);
    if (!v || v->size() != 1) return std::nullopt;
    return v->front();
}

/// DICOM TM ("HHMMSS.FFFFFF", or the old "HH:MM:SS.frac") as seconds since midnight.
std::optional<double> parseTime(const std::string& text) {
    std::string t;
    for (char c : trim(text)) {
        if (c != ':') t.push_back(c);
    }
    if (t.size() < 2) return std::nullopt;
    const std::size_t dot = t.find('.');
    const std::string whole = t.substr(0, dot);
    if (whole.size() % 2 != 0 || whole.size() > 6 ||
        !std::all_of(whole.begin(), whole.end(), [](char c) { return c >= '0' && c <= '9'; })) {
        return std::nullopt;
    }
    double seconds = 0;
    const double scale[3] = {3600, 60, 1};
    for (std::size_t i = 0; i * 2 < whole.size(); ++i) {
        seconds += scale[i] * std::stod(whole.substr(i * 2, 2));
    }
    if (dot != std::string::npos && dot + 1 < t.size()) {
        const auto frac = parseNumber("0." + t.substr(dot + 1));
        if (!frac) return std::nullopt;
        seconds += *frac;
    }
    return seconds;
}

/// What a structural walk of a file found. GDCM (as Debian builds it) aborts on an assertion
/// for some files that end inside an element header, so files are checked here, by reading
/// element headers and skipping values, before GDCM sees them.
struct Walk {
    bool isPart10 = false;     // "DICM" at byte 128
    bool complete = false;     // every header and value through the end of Pixel Data fits
    bool inPixelData = false;  // the damage lies in the Pixel Data value
    bool noPixelData = false;  // an image file that ends cleanly before Pixel Data
    std::string problem;       // what is wrong, for messages
    std::string seriesUid;     // (0020,000e) when it was reached
    int rows = 0, cols = 0, bitsAllocated = 0;
    std::uint64_t size = 0;
};

bool isLongVr(const char* vr) {
    static const char* const kLong[] = {"OB", "OD", "OF", "OL", "OV", "OW", "SQ",
                                        "SV", "UC", "UN", "UR", "UT", "UV"};
    for (const char* l : kLong) {
        if (vr[0] == l[0] && vr[1] == l[1]) return true;
    }
    return false;
}

Walk walkFile(const fs::path& path) {
    Walk w;
    std::error_code ec;
    w.size = fs::file_size(path, ec);
    if (ec || w.size < 132) return w;
    std::ifstream in(path, std::ios::binary);
    char preamble[132];
    if (!in.read(preamble, 132) || std::memcmp(preamble + 128, "DICM", 4) != 0) return w;
    w.isPart10 = true;
    const std::uint64_t size = w.size;
    const auto readAt = [&](std::uint64_t at, unsigned char* buf, std::size_t n) {
        if (at + n > size) return false;
        in.seekg(static_cast<std::streamoff>(at));
        return static_cast<bool>(
            in.read(reinterpret_cast<char*>(buf), static_cast<std::streamsize>(n)));
    };
    const auto fail = [&](const std::string& what, std::uint64_t at) {
        w.problem = what + " at byte " + std::to_string(at) + " of a " + std::to_string(size) +
                    "-byte file";
        return w;
    };
    bool metaDone = false, explicitVr = true, bigEndian = false, pixelData = false;
    std::string transferSyntax, mediaStorage;
    int depth = 0;  // open undefined-length sequences and items
    std::uint64_t pos = 132;
    while (pos < size) {
        unsigned char h[8];
        if (!readAt(pos, h, 4)) return fail("a truncated element header", pos);
        if (!metaDone && (h[0] | h[1] << 8) != 0x0002) {
            metaDone = true;
            if (transferSyntax == "1.2.840.10008.1.2") explicitVr = false;
            if (transferSyntax == "1.2.840.10008.1.2.2") bigEndian = true;
            if (transferSyntax == "1.2.840.10008.1.2.1.99") {  // deflated: GDCM inflates and checks
                w.complete = true;
                return w;
            }
        }
        const bool be = metaDone && bigEndian;
        const auto u16 = [&](const unsigned char* b) {
            return static_cast<std::uint32_t>(be ? (b[0] << 8 | b[1]) : (b[1] << 8 | b[0]));
        };
        const auto u32 = [&](const unsigned char* b) {
            return be ? (static_cast<std::uint32_t>(b[0]) << 24 |
                         static_cast<std::uint32_t>(b[1]) << 16 |
                         static_cast<std::uint32_t>(b[2]) << 8 | b[3])
                      : (static_cast<std::uint32_t>(b[3]) << 24 |
                         static_cast<std::uint32_t>(b[2]) << 16 |
                         static_cast<std::uint32_t>(b[1]) << 8 | b[0]);
        };
        const std::uint32_t group = u16(h), element = u16(h + 2);
        const std::uint64_t start = pos;
        std::uint32_t length = 0;
        char vr[2] = {0, 0};
        if (group == 0xFFFE) {  // item and delimiters: no VR
            if (!readAt(pos + 4, h, 4)) return fail("a truncated item header", start);
            length = u32(h);
            pos += 8;
        } else if (!metaDone || explicitVr) {
            if (!readAt(pos + 4, h, 4)) return fail("a truncated element header", start);
            vr[0] = static_cast<char>(h[0]);
            vr[1] = static_cast<char>(h[1]);
            if (vr[0] < 'A' || vr[0] > 'Z' || vr[1] < 'A' || vr[1] > 'Z')
                return fail("an invalid value representation", start);
            if (isLongVr(vr)) {
                if (!readAt(pos + 8, h, 4)) return fail("a truncated element header", start);
                length = u32(h);
                pos += 12;
            } else {
                length = u16(h + 2);
                pos += 8;
            }
        } else {
            if (!readAt(pos + 4, h, 4)) return fail("a truncated element header", start);
            length = u32(h);
            pos += 8;
        }
        const bool undefined = length == 0xFFFFFFFFu;
        if (group == 0xFFFE) {
            if (element == 0xE000 && !undefined) {
                if (pos + length > size) {
                    w.inPixelData = pixelData;
                    return fail(
                        pixelData ? "a truncated pixel data fragment" : "a truncated sequence item",
                        start);
                }
                pos += length;
            } else if (element == 0xE000) {
                ++depth;
            } else if (element == 0xE0DD && pixelData && depth == 0) {
                w.complete = true;
                return w;
            } else if (element == 0xE00D || element == 0xE0DD) {
                if (depth == 0) return fail("an unmatched delimiter", start);
                --depth;
            }
            continue;
        }
        if (undefined) {
            if (group == 0x7FE0 && element == 0x0010 && depth == 0) {
                pixelData = true;  // encapsulated fragments follow
            } else if (vr[0] == 'U' && vr[1] == 'N') {
                w.complete = true;  // implicit-VR content in an explicit file: leave it to GDCM
                return w;
            } else {
                ++depth;
            }
            continue;
        }
        if (depth == 0 && length <= 256 && pos + length <= size) {
            unsigned char v[256];
            if (readAt(pos, v, length)) {
                const std::string text = trim(std::string(reinterpret_cast<char*>(v), length));
                const std::uint32_t tag = group << 16 | element;
                if (tag == 0x00020010u) transferSyntax = text;
                if (tag == 0x00020002u) mediaStorage = text;
                if (tag == 0x0020000Eu) w.seriesUid = text;
                if (length == 2 && tag == 0x00280010u) w.rows = static_cast<int>(u16(v));
                if (length == 2 && tag == 0x00280011u) w.cols = static_cast<int>(u16(v));
                if (length == 2 && tag == 0x00280100u) w.bitsAllocated = static_cast<int>(u16(v));
            }
        }
        if (pos + length > size) {
            w.inPixelData = group == 0x7FE0 && element == 0x0010;
            return fail(w.inPixelData
                            ? "a truncated pixel data value of " + std::to_string(length) + " bytes"
                            : "a truncated element value",
                        start);
        }
        pos += length;
        if (group == 0x7FE0 && element == 0x0010 && depth == 0) {
            w.complete = true;  // what follows Pixel Data (padding) does not matter
            return w;
        }
    }
    if (!metaDone) return fail("the end of the file within its file meta information", pos);
    // An image storage object that ends cleanly before any Pixel Data was cut short.
    if (!mediaStorage.empty() &&
        gdcm::MediaStorage::IsImage(gdcm::MediaStorage::GetMSType(mediaStorage.c_str()))) {
        w.noPixelData = true;
        return fail(
            "the end of an image file (SOP class " + mediaStorage + ") before any Pixel Data", pos);
    }
    if (depth != 0 || pixelData) return fail("an unterminated sequence", pos);
    w.complete = true;
    return w;
}

/// What the header scan found in one file.
struct Header {
    fs::path path;
    std::map<gdcm::Tag, std::string> values;  // trimmed values of the scanned tags present

    const std::string* get(const gdcm::Tag& t) const {
        const auto it = values.find(t);
        return it == values.end() || it->second.empty() ? nullptr : &it->second;
    }
    std::string text(const gdcm::Tag& t) const {
        const std::string* v = get(t);
        return v ? *v : std::string();
    }
    std::optional<double> number(const gdcm::Tag& t) const {
        const std::string* v = get(t);
        return v ? parseNumber(*v) : std::nullopt;
    }
    int integer(const gdcm::Tag& t, int fallback) const {
        const auto v = number(t);
        if (!v || *v < 0 || *v > 1e9) return fallback;
        return static_cast<int>(*v);
    }
    bool isImage() const { return integer(kRows, 0) > 0 && integer(kColumns, 0) > 0; }
};

struct Scan {
    std::string inputsName;  // for messages: the input directory or file(s)
    std::size_t fileCount = 0;
    std::vector<Header> headers;                     // DICOM files only
    std::vector<std::pair<fs::path, Walk>> damaged;  // DICOM files GDCM must not see
};

[[noreturn]] void throwDamaged(const fs::path& file, const Walk& w) {
    if (w.noPixelData) {
        throw FormatError(file.string() + ": expected Pixel Data (7fe0,0010) of " +
                          std::to_string(w.cols) + "x" + std::to_string(w.rows) + "x" +
                          std::to_string(w.bitsAllocated) + " bits, found none: " + w.problem +
                          " (the file is truncated or its pixel data was removed)");
    }
    if (w.inPixelData) {
        throw FormatError(file.string() + ": expected complete pixel data of " +
                          std::to_string(w.cols) + "x" + std::to_string(w.rows) + "x" +
                          std::to_string(w.bitsAllocated) + " bits, found " + w.problem +
                          " (the file is truncated)");
    }
    throw FormatError(file.string() + ": expected a complete DICOM header, found " + w.problem +
                      (w.seriesUid.empty()
                           ? std::string(" (its series cannot be told, so it is refused; remove it "
                                         "or list the other files explicitly)")
                           : std::string(" (series " + w.seriesUid + ")")));
}

std::string describeInputs(const std::vector<fs::path>& inputs) {
    if (inputs.empty()) return "DICOM input";
    std::string s = inputs.front().string();
    if (inputs.size() > 1) s += " (and " + std::to_string(inputs.size() - 1) + " more inputs)";
    return s;
}

void quietGdcm() {
    gdcm::Trace::SetDebug(false);
    gdcm::Trace::SetWarning(false);
    gdcm::Trace::SetError(false);
}

Scan scanHeaders(const std::vector<fs::path>& inputs) {
    quietGdcm();
    Scan scan;
    scan.inputsName = describeInputs(inputs);
    std::vector<std::string> files;
    for (const fs::path& in : inputs) {
        std::error_code ec;
        if (!fs::exists(in, ec)) {
            throw IoError(in.string() + ": expected an existing file or directory, found nothing");
        }
        if (fs::is_directory(in, ec)) {
            fs::recursive_directory_iterator it(in, fs::directory_options::skip_permission_denied,
                                                ec);
            if (ec)
                throw IoError(in.string() +
                              ": expected a readable directory, found an error: " + ec.message());
            for (const fs::recursive_directory_iterator end; it != end; it.increment(ec)) {
                if (ec) break;
                std::error_code fec;
                if (it->is_regular_file(fec)) files.push_back(it->path().string());
            }
            if (ec)
                throw IoError(in.string() +
                              ": expected a readable directory, found an error: " + ec.message());
        } else {
            files.push_back(in.string());
        }
    }
    std::sort(files.begin(), files.end());
    files.erase(std::unique(files.begin(), files.end()), files.end());
    scan.fileCount = files.size();
    if (files.empty()) return scan;

    const gdcm::Tag tags[] = {
        kSopClassUid,       kAcquisitionTime, kContentTime,      kModality,
        kSeriesDescription, kGantryTilt,      kSeriesUid,        kAcquisitionNumber,
        kInstanceNumber,    kImagePosition,   kImageOrientation, kTemporalPosition,
        kSamplesPerPixel,   kPhotometric,     kNumberOfFrames,   kRows,
        kColumns,           kPixelSpacing,    kBitsAllocated,    kRescaleIntercept,
        kRescaleSlope};
    // Only DICOM Part 10 files ("DICM" at byte 128) are read, and only those whose structure is
    // complete reach GDCM.
    std::vector<std::string> complete;
    for (const std::string& f : files) {
        Walk w = walkFile(f);
        if (!w.isPart10) continue;
        if (w.complete) {
            complete.push_back(f);
        } else {
            scan.damaged.emplace_back(f, std::move(w));
        }
    }
    files.swap(complete);
    gdcm::Scanner scanner;
    for (const gdcm::Tag& t : tags) scanner.AddTag(t);
    if (!files.empty())
        scanner.Scan(files);  // false only when no file at all was DICOM; IsKey tells per file
    for (const std::string& f : files) {
        if (!scanner.IsKey(f.c_str())) continue;
        Header h;
        h.path = f;
        for (const auto& [tag, value] : scanner.GetMapping(f.c_str())) {
            if (value) h.values[tag] = trim(value);
        }
        // A file GDCM parsed but that carries none of the tags every DICOM object has is not
        // DICOM for our purposes (GDCM accepts some raw data sets without preamble).
        if (!h.get(kSopClassUid) && !h.get(kSeriesUid) && !h.isImage()) continue;
        scan.headers.push_back(std::move(h));
    }
    return scan;
}

[[noreturn]] void throwNoDicom(const Scan& scan) {
    if (scan.fileCount == 0) {
        throw FormatError(scan.inputsName + ": expected DICOM files, found none (no files)");
    }
    throw FormatError(scan.inputsName + ": expected DICOM files, found none among " +
                      std::to_string(scan.fileCount) + " files");
}

/// The series of a scan, in the order of DicomSeriesInfo (description, then UID).
struct SeriesGroup {
    std::string uid;
    std::vector<const Header*> files;   // all files of the series
    std::vector<const Header*> images;  // those with Rows and Columns
};

std::vector<SeriesGroup> groupSeries(const Scan& scan) {
    std::map<std::string, SeriesGroup> byUid;
    for (const Header& h : scan.headers) {
        SeriesGroup& g = byUid[h.text(kSeriesUid)];
        g.uid = h.text(kSeriesUid);
        g.files.push_back(&h);
        if (h.isImage()) g.images.push_back(&h);
    }
    std::vector<SeriesGroup> out;
    for (auto& [uid, g] : byUid) out.push_back(std::move(g));
    const auto desc = [](const SeriesGroup& g) {
        return g.files.front()->text(kSeriesDescription);
    };
    std::stable_sort(out.begin(), out.end(), [&](const SeriesGroup& a, const SeriesGroup& b) {
        const std::string da = desc(a), db = desc(b);
        return da != db ? da < db : a.uid < b.uid;
    });
    return out;
}

/// Unit slice normal from a header's orientation, if it has a usable one.
std::optional<Eigen::Vector3d> normalOf(const Header& h) {
    const std::string* iop = h.get(kImageOrientation);
    if (!iop) return std::nullopt;
    const auto v = parseNumbers(*iop);
    if (!v || v->size() != 6) return std::nullopt;
    const Eigen::Vector3d r((*v)[0], (*v)[1], (*v)[2]);
    const Eigen::Vector3d c((*v)[3], (*v)[4], (*v)[5]);
    const Eigen::Vector3d n = r.cross(c);
    if (!(n.norm() > 0.5)) return std::nullopt;
    return n.normalized();
}

std::optional<Eigen::Vector3d> positionOf(const Header& h) {
    const std::string* ipp = h.get(kImagePosition);
    if (!ipp) return std::nullopt;
    const auto v = parseNumbers(*ipp);
    if (!v || v->size() != 3) return std::nullopt;
    return Eigen::Vector3d((*v)[0], (*v)[1], (*v)[2]);
}

/// Tolerance (mm) below which two slice positions along the normal count as the same.
double positionTolerance(const Header& h) {
    double spacing = 1.0;
    if (const std::string* ps = h.get(kPixelSpacing)) {
        if (const auto v = parseNumbers(*ps); v && v->size() == 2 && (*v)[0] > 0 && (*v)[1] > 0) {
            spacing = std::min((*v)[0], (*v)[1]);
        }
    }
    return 0.02 * spacing;
}

/// Groups images by position along the normal @p n; groups in increasing position.
/// Images without a position each form their own group.
std::vector<std::vector<const Header*>> groupPositions(const std::vector<const Header*>& images,
                                                       const Eigen::Vector3d& n, double tolMm) {
    std::vector<std::pair<double, const Header*>> along;
    std::vector<std::vector<const Header*>> groups;
    for (const Header* h : images) {
        if (const auto p = positionOf(*h)) {
            along.emplace_back(p->dot(n), h);
        } else {
            groups.push_back({h});
        }
    }
    std::stable_sort(along.begin(), along.end(),
                     [](const auto& a, const auto& b) { return a.first < b.first; });
    double groupStart = 0;
    for (std::size_t i = 0; i < along.size(); ++i) {
        if (i == 0 || along[i].first - groupStart > tolMm) {
            groups.emplace_back();
            groupStart = along[i].first;
        }
        groups.back().push_back(along[i].second);
    }
    return groups;
}

DicomSeriesInfo describeSeries(const SeriesGroup& g) {
    DicomSeriesInfo info;
    info.uid = g.uid;
    info.description = g.files.front()->text(kSeriesDescription);
    info.modality = g.files.front()->text(kModality);
    info.imageCount = static_cast<int>(g.images.size());
    for (const Header* h : g.files) info.files.push_back(h->path);
    if (g.images.empty()) {
        info.positionCount = 0;
        info.timePointCount = 0;
        return info;
    }
    const auto n = normalOf(*g.images.front());
    if (!n) {
        info.positionCount = info.imageCount;
        return info;
    }
    const auto groups = groupPositions(g.images, *n, positionTolerance(*g.images.front()));
    info.positionCount = static_cast<int>(groups.size());
    std::size_t most = 0;
    for (const auto& grp : groups) most = std::max(most, grp.size());
    info.timePointCount = info.imageCount % info.positionCount == 0
                              ? info.imageCount / info.positionCount
                              : static_cast<int>(most);
    return info;
}

std::string listSeries(const std::vector<SeriesGroup>& groups) {
    std::string s;
    for (const SeriesGroup& g : groups) {
        const std::string desc = g.files.front()->text(kSeriesDescription);
        s += "\n  " + (g.uid.empty() ? std::string("(no SeriesInstanceUID)") : g.uid) + "  \"" +
             desc + "\"  " + std::to_string(g.images.size()) + " images";
        if (g.images.size() != g.files.size()) {
            s += ", " + std::to_string(g.files.size() - g.images.size()) + " non-image files";
        }
    }
    return s;
}

const SeriesGroup& chooseSeries(const Scan& scan, const std::vector<SeriesGroup>& groups,
                                const LoadOptions& options) {
    if (options.seriesUid) {
        for (const SeriesGroup& g : groups) {
            if (g.uid == *options.seriesUid) return g;
        }
        throw ValueError(scan.inputsName + ": expected series " + *options.seriesUid +
                         ", found only these series:" + listSeries(groups));
    }
    std::vector<const SeriesGroup*> withImages;
    for (const SeriesGroup& g : groups) {
        if (!g.images.empty()) withImages.push_back(&g);
    }
    if (withImages.size() == 1) return *withImages.front();
    if (withImages.empty()) {
        const Header& h = *groups.front().files.front();
        throw FormatError(
            h.path.string() + ": expected DICOM images (Rows, Columns, Pixel Data), found " +
            std::to_string(scan.headers.size()) + " DICOM files without images (SOP class " +
            (h.text(kSopClassUid).empty() ? std::string("unknown") : h.text(kSopClassUid)) + ")");
    }
    throw ValueError(scan.inputsName + ": expected one DICOM series, found " +
                     std::to_string(withImages.size()) +
                     "; choose one with --series UID:" + listSeries(groups));
}

/// Orders the images of one position in time: TemporalPositionIdentifier, AcquisitionNumber,
/// AcquisitionTime (or ContentTime), InstanceNumber, file name. A key is used only when every
/// image of the series has it, so the comparison stays a strict weak order.
struct TimeOrder {
    bool useTemporal = true, useAcqNumber = true, useAcqTime = true, useContentTime = true,
         useInstance = true;

    explicit TimeOrder(const std::vector<const Header*>& images) {
        for (const Header* h : images) {
            useTemporal = useTemporal && h->number(kTemporalPosition).has_value();
            useAcqNumber = useAcqNumber && h->number(kAcquisitionNumber).has_value();
            useAcqTime = useAcqTime && parseTime(h->text(kAcquisitionTime)).has_value();
            useContentTime = useContentTime && parseTime(h->text(kContentTime)).has_value();
            useInstance = useInstance && h->number(kInstanceNumber).has_value();
        }
    }

    std::vector<double> key(const Header& h) const {
        std::vector<double> k;
        if (useTemporal) k.push_back(*h.number(kTemporalPosition));
        if (useAcqNumber) k.push_back(*h.number(kAcquisitionNumber));
        if (useAcqTime) {
            k.push_back(*parseTime(h.text(kAcquisitionTime)));
        } else if (useContentTime) {
            k.push_back(*parseTime(h.text(kContentTime)));
        }
        if (useInstance) k.push_back(*h.number(kInstanceNumber));
        return k;
    }
};

/// Parsed, checked geometry of one file (mm and unit cosines, as in DICOM).
struct FileGeometry {
    Eigen::Vector3d position;
    Eigen::Vector3d rowCosine, columnCosine;
    double rowSpacing = 0, columnSpacing = 0;  // PixelSpacing[0], PixelSpacing[1]
};

FileGeometry geometryOf(const Header& h) {
    const std::string file = h.path.string();
    const auto need = [&](const gdcm::Tag& t, const char* name, std::size_t count) {
        const std::string* v = h.get(t);
        if (!v) {
            throw FormatError(file + ": expected " + name + " with " + std::to_string(count) +
                              " numbers, found none (tag missing)");
        }
        const auto nums = parseNumbers(*v);
        if (!nums || nums->size() != count) {
            throw FormatError(file + ": expected " + name + " with " + std::to_string(count) +
                              " numbers, found '" + *v + "'");
        }
        return *nums;
    };
    const auto ipp = need(kImagePosition, "Image Position (Patient) (0020,0032)", 3);
    const auto iop = need(kImageOrientation, "Image Orientation (Patient) (0020,0037)", 6);
    const auto ps = need(kPixelSpacing, "Pixel Spacing (0028,0030)", 2);
    FileGeometry g;
    g.position = Eigen::Vector3d(ipp[0], ipp[1], ipp[2]);
    g.rowCosine = Eigen::Vector3d(iop[0], iop[1], iop[2]);
    g.columnCosine = Eigen::Vector3d(iop[3], iop[4], iop[5]);
    const double rn = g.rowCosine.norm(), cn = g.columnCosine.norm();
    if (std::abs(rn - 1) > 0.01 || std::abs(cn - 1) > 0.01 ||
        std::abs(g.rowCosine.dot(g.columnCosine)) > 0.01) {
        throw FormatError(
            file +
            ": expected Image Orientation (Patient) (0020,0037) with two orthogonal unit "
            "vectors, found '" +
            h.text(kImageOrientation) + "'");
    }
    g.rowCosine /= rn;
    g.columnCosine /= cn;
    g.rowSpacing = ps[0];
    g.columnSpacing = ps[1];
    if (!(ps[0] > 0) || !(ps[1] > 0)) {
        throw FormatError(
            file + ": expected Pixel Spacing (0028,0030) with two positive numbers, found '" +
            h.text(kPixelSpacing) + "'");
    }
    return g;
}

std::string pixelDescription(int cols, int rows, int bits) {
    return std::to_string(cols) + "x" + std::to_string(rows) + "x" + std::to_string(bits) + " bits";
}

/// Explains why gdcm::ImageReader could not read @p h: no pixel data, or a damaged file.
[[noreturn]] void throwUnreadable(const Header& h) {
    const std::string file = h.path.string();
    std::error_code ec;
    const auto size = fs::file_size(h.path, ec);
    const std::string sizeText = ec ? std::string("unknown size") : std::to_string(size) + " bytes";
    const std::string expectedPixels =
        pixelDescription(h.integer(kColumns, 0), h.integer(kRows, 0), h.integer(kBitsAllocated, 0));
    gdcm::Reader reader;
    reader.SetFileName(file.c_str());
    if (reader.Read()) {
        const gdcm::DataSet& ds = reader.GetFile().GetDataSet();
        if (!ds.FindDataElement(kPixelData)) {
            throw FormatError(
                file + ": expected Pixel Data (7fe0,0010) of " + expectedPixels +
                ", found none (the file has no pixel data; SOP class " +
                (h.text(kSopClassUid).empty() ? std::string("unknown") : h.text(kSopClassUid)) +
                ")");
        }
        throw FormatError(file + ": expected decodable pixel data of " + expectedPixels +
                          ", found pixel data GDCM cannot decode");
    }
    throw FormatError(file + ": expected complete pixel data of " + expectedPixels +
                      ", found a truncated or corrupt file (" + sizeText + ")");
}

/// GDCM accepts a file whose pixel data is cut short, with only a warning, and pads it (and
/// some codecs then decode the padding without complaint). Find where the Pixel Data value
/// starts and refuse a file that ends before its declared length. Deflated files cannot be
/// checked this way (their offsets are in the inflated stream); a truncated deflate stream
/// fails to parse instead.
void checkComplete(const Header& h, const gdcm::File& file, int cols, int rows, int bits) {
    const gdcm::DataSet& ds = file.GetDataSet();
    const std::string name = h.path.string();
    if (!ds.FindDataElement(kPixelData)) {
        throw FormatError(name + ": expected Pixel Data (7fe0,0010) of " +
                          pixelDescription(cols, rows, bits) + ", found none");
    }
    const gdcm::DataElement& pixels = ds.GetDataElement(kPixelData);
    const gdcm::TransferSyntax& ts = file.GetHeader().GetDataSetTransferSyntax();
    if (ts == gdcm::TransferSyntax::DeflatedExplicitVRLittleEndian) return;
    // Bytes of the element's value as declared: the plain length, or for encapsulated data the
    // offset table, every fragment (with item headers) and the delimiter.
    std::uint64_t declared = 0;
    if (pixels.GetVL().IsUndefined()) {
        const gdcm::SequenceOfFragments* fragments = pixels.GetSequenceOfFragments();
        if (!fragments) return;
        declared = static_cast<std::uint32_t>(fragments->ComputeLength());
    } else {
        declared = static_cast<std::uint32_t>(pixels.GetVL());
    }
    std::error_code ec;
    const auto size = fs::file_size(h.path, ec);
    if (ec) return;
    gdcm::Reader headerReader;
    headerReader.SetFileName(name.c_str());
    const std::set<gdcm::Tag> skip{kPixelData};
    if (!headerReader.ReadUpToTag(kPixelData, skip)) return;
    // Reading up to a skipped tag leaves the stream at the start of that element's value.
    const std::uint64_t start = headerReader.GetStreamCurrentPosition();
    const std::uint64_t end = start + declared;
    if (end > size) {
        throw FormatError(name + ": expected complete pixel data of " +
                          pixelDescription(cols, rows, bits) + " (" + std::to_string(declared) +
                          " bytes ending at byte " + std::to_string(end) +
                          "), found a truncated file of " + std::to_string(size) + " bytes");
    }
}

/// Converts one decoded frame to rescaled floats.
template <typename T>
void convertPixels(const char* raw, std::size_t count, int bitsStored, int highBit, bool isSigned,
                   double slope, double intercept, std::vector<float>& out) {
    out.resize(count);
    const bool maskBits = std::is_integral_v<T> && bitsStored > 0 &&
                          bitsStored < static_cast<int>(8 * sizeof(T)) && highBit + 1 == bitsStored;
    const std::int64_t mask = maskBits ? (std::int64_t{1} << bitsStored) - 1 : 0;
    const std::int64_t signBit = maskBits ? std::int64_t{1} << (bitsStored - 1) : 0;
    for (std::size_t i = 0; i < count; ++i) {
        T v;
        std::memcpy(&v, raw + i * sizeof(T), sizeof(T));
        double stored;
        if constexpr (std::is_integral_v<T>) {
            std::int64_t s = static_cast<std::int64_t>(v);
            if (maskBits) {
                s &= mask;  // drop overlay bits above the high bit
                if (isSigned && (s & signBit)) s -= std::int64_t{1} << bitsStored;
            }
            stored = static_cast<double>(s);
        } else {
            stored = static_cast<double>(v);
        }
        out[i] = static_cast<float>(slope * stored + intercept);
    }
}

/// Converts one frame of @p pf pixels at @p raw to rescaled floats.
void convertFrame(const std::string& file, const char* raw, const gdcm::PixelFormat& pf,
                  std::size_t count, double slope, double intercept, std::vector<float>& out) {
    const int bitsStored = pf.GetBitsStored();
    const int highBit = pf.GetHighBit();
    const bool isSigned = pf.GetPixelRepresentation() == 1;
    switch (pf.GetScalarType()) {
        case gdcm::PixelFormat::UINT8:
            convertPixels<std::uint8_t>(raw, count, bitsStored, highBit, false, slope, intercept,
                                        out);
            break;
        case gdcm::PixelFormat::INT8:
            convertPixels<std::int8_t>(raw, count, bitsStored, highBit, isSigned, slope, intercept,
                                       out);
            break;
        case gdcm::PixelFormat::UINT16:
            convertPixels<std::uint16_t>(raw, count, bitsStored, highBit, false, slope, intercept,
                                         out);
            break;
        case gdcm::PixelFormat::INT16:
            convertPixels<std::int16_t>(raw, count, bitsStored, highBit, isSigned, slope, intercept,
                                        out);
            break;
        case gdcm::PixelFormat::UINT32:
            convertPixels<std::uint32_t>(raw, count, bitsStored, highBit, false, slope, intercept,
                                         out);
            break;
        case gdcm::PixelFormat::INT32:
            convertPixels<std::int32_t>(raw, count, bitsStored, highBit, isSigned, slope, intercept,
                                        out);
            break;
        case gdcm::PixelFormat::FLOAT32:
            convertPixels<float>(raw, count, 0, 0, true, slope, intercept, out);
            break;
        case gdcm::PixelFormat::FLOAT64:
            convertPixels<double>(raw, count, 0, 0, true, slope, intercept, out);
            break;
        default:
            throw FormatError(file + ": expected 8, 16 or 32-bit integer or float pixels, found " +
                              std::string(pf.GetScalarTypeAsString()));
    }
}

/// Reads @p h with @p reader and decodes all of its @p frames frames into @p buffer, checking
/// the result against the header's Rows and Columns.
void decodeFile(const Header& h, int frames, gdcm::ImageReader& reader, std::vector<char>& buffer) {
    const std::string file = h.path.string();
    const int rows = h.integer(kRows, 0);
    const int cols = h.integer(kColumns, 0);
    reader.SetFileName(file.c_str());
    if (!reader.Read()) throwUnreadable(h);
    const gdcm::Image& image = reader.GetImage();
    const gdcm::PixelFormat& pf = image.GetPixelFormat();
    checkComplete(h, reader.GetFile(), cols, rows, pf.GetBitsAllocated());
    if (pf.GetSamplesPerPixel() != 1) {
        throw FormatError(file + ": expected a grayscale image (1 sample per pixel), found " +
                          std::to_string(pf.GetSamplesPerPixel()) + " samples per pixel (" +
                          h.text(kPhotometric) + "); colour images are not supported");
    }
    if (image.GetDimension(0) != static_cast<unsigned>(cols) ||
        image.GetDimension(1) != static_cast<unsigned>(rows)) {
        throw FormatError(file + ": expected " + std::to_string(cols) + "x" + std::to_string(rows) +
                          " pixels as the header says, found " +
                          std::to_string(image.GetDimension(0)) + "x" +
                          std::to_string(image.GetDimension(1)) + " decoded");
    }
    const std::size_t count = static_cast<std::size_t>(rows) * static_cast<std::size_t>(cols) *
                              static_cast<std::size_t>(frames);
    const std::size_t pixelBytes = pf.GetPixelSize();
    const unsigned long length = image.GetBufferLength();
    if (pixelBytes == 0 || length < count * pixelBytes || length > 2 * count * pixelBytes) {
        throw FormatError(
            file + ": expected pixel data of " +
            pixelDescription(cols, rows, pf.GetBitsAllocated()) +
            (frames > 1 ? " x " + std::to_string(frames) + " frames" : std::string()) + ", found " +
            std::to_string(length) + " bytes");
    }
    buffer.resize(length);
    if (!image.GetBuffer(buffer.data())) {
        const gdcm::TransferSyntax& ts = image.GetTransferSyntax();
        const char* tsName = gdcm::TransferSyntax::GetTSString(ts);
        throw FormatError(file + ": expected complete pixel data of " +
                          pixelDescription(cols, rows, pf.GetBitsAllocated()) +
                          " (transfer syntax " +
                          (tsName ? std::string(tsName) : std::string("unknown")) +
                          "), found a truncated file or data that cannot be decoded");
    }
}

double checkedSlope(const std::string& file, const std::optional<double>& slope,
                    const std::string& text) {
    if (slope && *slope == 0) {
        throw FormatError(file + ": expected a non-zero Rescale Slope (0028,1053), found '" + text +
                          "'");
    }
    return slope.value_or(1.0);
}

/// Decodes one single-frame image into @p slice (values rescaled with the file's own slope and
/// intercept). Geometry is filled by the caller.
void decodeSlice(const Header& h, Slice& slice) {
    const std::string file = h.path.string();
    const double slope = checkedSlope(file, h.number(kRescaleSlope), h.text(kRescaleSlope));
    const double intercept = h.number(kRescaleIntercept).value_or(0.0);
    gdcm::ImageReader reader;
    std::vector<char> buffer;
    decodeFile(h, 1, reader, buffer);
    slice.cols = h.integer(kColumns, 0);
    slice.rows = h.integer(kRows, 0);
    slice.source = file;
    const std::size_t count =
        static_cast<std::size_t>(slice.rows) * static_cast<std::size_t>(slice.cols);
    convertFrame(file, buffer.data(), reader.GetImage().GetPixelFormat(), count, slope, intercept,
                 slice.values);
}

// Enhanced (functional group) multi-frame tags.
const gdcm::Tag kSharedGroups(0x5200, 0x9229);
const gdcm::Tag kPerFrameGroups(0x5200, 0x9230);
const gdcm::Tag kPixelMeasuresSequence(0x0028, 0x9110);
const gdcm::Tag kPlanePositionSequence(0x0020, 0x9113);
const gdcm::Tag kPlaneOrientationSequence(0x0020, 0x9116);
const gdcm::Tag kValueTransformSequence(0x0028, 0x9145);

std::optional<std::string> elementText(const gdcm::DataSet& ds, const gdcm::Tag& t) {
    if (!ds.FindDataElement(t)) return std::nullopt;
    const gdcm::ByteValue* bv = ds.GetDataElement(t).GetByteValue();
    if (!bv) return std::nullopt;
    std::string s = trim(std::string(bv->GetPointer(), bv->GetLength()));
    if (s.empty()) return std::nullopt;
    return s;
}

/// Copies position, orientation, spacing and rescale of one functional group item into @p h.
void applyFunctionalGroup(const gdcm::DataSet& group, Header& h) {
    const std::pair<gdcm::Tag, gdcm::Tag> wanted[] = {
        {kPixelMeasuresSequence, kPixelSpacing},
        {kPlanePositionSequence, kImagePosition},
        {kPlaneOrientationSequence, kImageOrientation},
        {kValueTransformSequence, kRescaleSlope},
        {kValueTransformSequence, kRescaleIntercept}};
    for (const auto& [sequence, tag] : wanted) {
        if (!group.FindDataElement(sequence)) continue;
        const gdcm::SmartPointer<gdcm::SequenceOfItems> items =
            group.GetDataElement(sequence).GetValueAsSQ();
        if (!items || items->GetNumberOfItems() == 0) continue;
        if (auto v = elementText(items->GetItem(1).GetNestedDataSet(), tag)) h.values[tag] = *v;
    }
}

/// The time point to read, checked against @p count; -1 for a 3D source without a choice.
int chooseTimePoint(const std::string& name, int count, const LoadOptions& options) {
    if (count > 1 && !options.timePoint) {
        throw ValueError(name + ": expected --volume N to choose one of the " +
                         std::to_string(count) + " time points (0-" + std::to_string(count - 1) +
                         "), found none");
    }
    if (!options.timePoint) return -1;
    const int t = *options.timePoint;
    if (t < 0 || t >= count) {
        throw ValueError(name + ": expected --volume between 0 and " + std::to_string(count - 1) +
                         " (" + std::to_string(count) + " time point" + (count > 1 ? "s" : "") +
                         "), found " + std::to_string(t));
    }
    return t;
}

/// Groups @p images by position and checks that every position holds the same number.
std::vector<std::vector<const Header*>> positionGroups(const std::string& name,
                                                       const std::vector<const Header*>& images,
                                                       const FileGeometry& first) {
    const Eigen::Vector3d normal = first.rowCosine.cross(first.columnCosine).normalized();
    const double tolMm = 0.02 * std::min(first.rowSpacing, first.columnSpacing);
    std::vector<std::vector<const Header*>> positions = groupPositions(images, normal, tolMm);
    const std::size_t timePoints = positions.front().size();
    for (const auto& grp : positions) {
        if (grp.size() != timePoints) {
            const auto& other = grp.size() < timePoints ? grp : positions.front();
            const double at = positionOf(*other.front())->dot(normal);
            throw ValueError(name +
                             ": expected the same number of images at every slice position (" +
                             std::to_string(timePoints) + " at the first), found " +
                             std::to_string(other.size()) + " at position " + std::to_string(at) +
                             " mm along the normal (e.g. " + other.front()->path.string() +
                             "); the series is incomplete or mixes acquisitions");
        }
    }
    return positions;
}

void checkMemory(const std::string& name, int cols, int rows, std::size_t slices,
                 std::uint64_t limit) {
    const long double bytes =
        static_cast<long double>(rows) * cols * static_cast<long double>(slices) * 4.0L;
    if (bytes > static_cast<long double>(limit)) {
        throw ValueError(name + ": expected at most " + std::to_string(limit) +
                         " bytes of decoded slices, found " + std::to_string(cols) + "x" +
                         std::to_string(rows) + "x" + std::to_string(slices) + " pixels (" +
                         std::to_string(static_cast<unsigned long long>(bytes)) +
                         " bytes as float)");
    }
}

void setGeometry(const FileGeometry& g, Slice& s) {
    s.position = g.position * 1e-3;
    s.colStep = g.rowCosine * (g.columnSpacing * 1e-3);
    s.rowStep = g.columnCosine * (g.rowSpacing * 1e-3);
}

void fillInfo(VolumeInfo& info, const Header& first, const std::vector<fs::path>& inputs,
              const std::string& uid, std::size_t positions, int timePoint, int timePointCount,
              bool rescaleVaries) {
    info.modality = first.text(kModality);
    info.valueUnits = info.modality == "CT" ? "HU" : "";
    info.sourceFormat = "DICOM";
    info.sourceDescription = first.text(kSeriesDescription);
    if (info.sourceDescription.empty()) {
        const fs::path in = inputs.front();
        info.sourceDescription =
            (in.has_filename() ? in.filename() : in.parent_path().filename()).string();
    }
    if (rescaleVaries)
        info.sourceDescription += " (rescale slope/intercept vary per slice; applied per slice)";
    info.seriesUid = uid;
    info.originalDims = {first.integer(kColumns, 0), first.integer(kRows, 0),
                         static_cast<std::int64_t>(positions)};
    info.rescaleSlope = first.number(kRescaleSlope).value_or(1.0);
    info.rescaleIntercept = first.number(kRescaleIntercept).value_or(0.0);
    info.gantryTiltDeg = first.number(kGantryTilt).value_or(0.0);
    info.timePoint = timePointCount > 1 ? timePoint : -1;
    info.timePointCount = timePointCount;
}

/// One enhanced multi-frame file: every frame's own position from the per-frame functional
/// groups (so uneven spacing is kept exactly), orientation, spacing and rescale from the
/// per-frame or shared groups. Repeated positions are time points in frame order.
SliceStack readMultiFrame(const Header& h, int frames, const std::string& name,
                          const std::string& uid, const std::vector<fs::path>& inputs,
                          const LoadOptions& options) {
    const std::string file = h.path.string();
    const int rows = h.integer(kRows, 0);
    const int cols = h.integer(kColumns, 0);
    // All frames are decoded at once, so the whole file counts against the budget.
    checkMemory(name, cols, rows, static_cast<std::size_t>(frames), options.maxSourceBytes);
    gdcm::ImageReader reader;
    std::vector<char> buffer;
    decodeFile(h, frames, reader, buffer);
    const gdcm::DataSet& ds = reader.GetFile().GetDataSet();
    if (!ds.FindDataElement(kPerFrameGroups)) {
        throw FormatError(
            file +
            ": expected a Per-frame Functional Groups Sequence (5200,9230) giving each of the " +
            std::to_string(frames) +
            " frames its position, found none (legacy multi-frame images are not supported)");
    }
    Header base = h;
    if (ds.FindDataElement(kSharedGroups)) {
        const auto shared = ds.GetDataElement(kSharedGroups).GetValueAsSQ();
        if (shared && shared->GetNumberOfItems() > 0)
            applyFunctionalGroup(shared->GetItem(1).GetNestedDataSet(), base);
    }
    const auto perFrame = ds.GetDataElement(kPerFrameGroups).GetValueAsSQ();
    const std::size_t items = perFrame ? perFrame->GetNumberOfItems() : 0;
    if (items != static_cast<std::size_t>(frames)) {
        throw FormatError(file + ": expected " + std::to_string(frames) +
                          " items in the Per-frame Functional Groups Sequence (5200,9230), found " +
                          std::to_string(items));
    }
    std::vector<Header> frameHeaders(items, base);
    std::vector<const Header*> framePtrs;
    for (std::size_t k = 0; k < items; ++k) {
        applyFunctionalGroup(perFrame->GetItem(k + 1).GetNestedDataSet(), frameHeaders[k]);
        frameHeaders[k].path = file + " (frame " + std::to_string(k + 1) + ")";
        framePtrs.push_back(&frameHeaders[k]);
    }
    const FileGeometry firstGeometry = geometryOf(frameHeaders.front());
    for (const Header& fh : frameHeaders) geometryOf(fh);
    auto positions = positionGroups(name, framePtrs, firstGeometry);
    const int timePointCount = static_cast<int>(positions.front().size());
    const int timePoint = chooseTimePoint(name, timePointCount, options);

    const gdcm::PixelFormat& pf = reader.GetImage().GetPixelFormat();
    const std::size_t count = static_cast<std::size_t>(rows) * static_cast<std::size_t>(cols);
    const std::size_t frameBytes = count * pf.GetPixelSize();
    SliceStack stack;
    stack.slices.resize(positions.size());
    bool rescaleVaries = false;
    const Header& first = frameHeaders.front();
    for (std::size_t i = 0; i < positions.size(); ++i) {
        auto& grp = positions[i];
        std::sort(grp.begin(), grp.end(), std::less<const Header*>());  // frame order
        const Header& fh = *grp[static_cast<std::size_t>(std::max(timePoint, 0))];
        const auto k = static_cast<std::size_t>(&fh - frameHeaders.data());
        Slice& s = stack.slices[i];
        setGeometry(geometryOf(fh), s);
        s.cols = cols;
        s.rows = rows;
        s.source = fh.path.string();
        const double slope =
            checkedSlope(s.source, fh.number(kRescaleSlope), fh.text(kRescaleSlope));
        const double intercept = fh.number(kRescaleIntercept).value_or(0.0);
        convertFrame(file, buffer.data() + k * frameBytes, pf, count, slope, intercept, s.values);
        rescaleVaries = rescaleVaries || slope != first.number(kRescaleSlope).value_or(1.0) ||
                        intercept != first.number(kRescaleIntercept).value_or(0.0);
    }
    fillInfo(stack.info, first, inputs, uid, positions.size(), timePoint, timePointCount,
             rescaleVaries);
    return stack;
}

std::string seriesName(const Scan& scan, const SeriesGroup& g) {
    const std::string desc = g.files.front()->text(kSeriesDescription);
    return desc.empty() ? scan.inputsName : scan.inputsName + " (series \"" + desc + "\")";
}

}  // namespace

std::vector<DicomSeriesInfo> scanDicom(const std::vector<fs::path>& inputs) {
    const Scan scan = scanHeaders(inputs);
    if (scan.headers.empty()) throwNoDicom(scan);
    std::vector<DicomSeriesInfo> out;
    for (const SeriesGroup& g : groupSeries(scan)) out.push_back(describeSeries(g));
    return out;
}

SliceStack readDicom(const std::vector<fs::path>& inputs, const LoadOptions& options) {
    const Scan scan = scanHeaders(inputs);
    if (scan.headers.empty() && !scan.damaged.empty())
        throwDamaged(scan.damaged.front().first, scan.damaged.front().second);
    if (scan.headers.empty()) throwNoDicom(scan);
    const std::vector<SeriesGroup> groups = groupSeries(scan);
    const SeriesGroup& series = chooseSeries(scan, groups, options);
    const std::string name = seriesName(scan, series);
    for (const auto& [file, walk] : scan.damaged) {
        if (walk.seriesUid.empty() || walk.seriesUid == series.uid) throwDamaged(file, walk);
    }

    for (const Header* h : series.files) {
        if (!h->isImage()) {
            throw FormatError(
                h->path.string() + ": expected an image of series " + series.uid +
                " (Rows, Columns, Pixel Data), found a file without them (SOP class " +
                (h->text(kSopClassUid).empty() ? std::string("unknown") : h->text(kSopClassUid)) +
                ")");
        }
        if (h->integer(kSamplesPerPixel, 1) != 1) {
            throw FormatError(h->path.string() +
                              ": expected a grayscale image (1 sample per pixel), found " +
                              h->text(kSamplesPerPixel) + " samples per pixel (" +
                              h->text(kPhotometric) + "); colour images are not supported");
        }
        const int frames = h->integer(kNumberOfFrames, 1);
        if (frames > 1) {
            if (series.images.size() == 1)
                return readMultiFrame(*h, frames, name, series.uid, inputs, options);
            throw FormatError(h->path.string() +
                              ": expected single-frame images or one multi-frame file, found a "
                              "multi-frame image of " +
                              std::to_string(frames) + " frames among " +
                              std::to_string(series.images.size()) + " images of the series");
        }
    }
    const std::vector<const Header*>& images = series.images;
    const Header& first = *images.front();
    const FileGeometry firstGeometry = geometryOf(first);
    for (const Header* h : images) geometryOf(*h);  // every file must carry its geometry
    std::vector<std::vector<const Header*>> positions = positionGroups(name, images, firstGeometry);
    const int timePointCount = static_cast<int>(positions.front().size());
    const int timePoint = chooseTimePoint(name, timePointCount, options);

    const TimeOrder order(images);
    std::vector<const Header*> chosen;
    for (auto& grp : positions) {
        std::stable_sort(grp.begin(), grp.end(), [&](const Header* a, const Header* b) {
            const auto ka = order.key(*a), kb = order.key(*b);
            return ka != kb ? ka < kb : a->path < b->path;
        });
        chosen.push_back(grp[static_cast<std::size_t>(std::max(timePoint, 0))]);
    }

    // Refuse before decoding anything that would not fit the memory budget.
    checkMemory(name, first.integer(kColumns, 0), first.integer(kRows, 0), chosen.size(),
                options.maxSourceBytes);

    SliceStack stack;
    stack.slices.resize(chosen.size());
    bool rescaleVaries = false;
    const double slope0 = first.number(kRescaleSlope).value_or(1.0);
    const double intercept0 = first.number(kRescaleIntercept).value_or(0.0);
    for (std::size_t i = 0; i < chosen.size(); ++i) {
        const Header& h = *chosen[i];
        Slice& s = stack.slices[i];
        decodeSlice(h, s);
        setGeometry(geometryOf(h), s);
        rescaleVaries = rescaleVaries || h.number(kRescaleSlope).value_or(1.0) != slope0 ||
                        h.number(kRescaleIntercept).value_or(0.0) != intercept0;
    }
    fillInfo(stack.info, first, inputs, series.uid, chosen.size(), timePoint, timePointCount,
             rescaleVaries);
    return stack;
}

}  // namespace palp::volume
