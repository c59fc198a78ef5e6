#include "dicom/dicom_header.h"

#include <gdcmTransferSyntax.h>
#include <gdcmUIDs.h>

#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <sstream>

#include "palp/base/bounds.h"
#include "palp/base/error.h"

namespace palp::volume::dicom {

namespace fs = std::filesystem;

bool gdcmKnowsTransferSyntax(const std::string& uid) {
    return gdcm::TransferSyntax::GetTSType(uid.c_str()) != gdcm::TransferSyntax::TS_END;
}

std::string describeTransferSyntax(const std::string& uid) {
    if (uid.empty()) return "no transfer syntax";
    if (gdcmKnowsTransferSyntax(uid)) {
        gdcm::UIDs known;
        const char* name = known.SetFromUID(uid.c_str()) ? known.GetName() : nullptr;
        return uid + " (" + (name && *name ? name : "known to GDCM") + ")";
    }
    // Syntaxes added to the standard after this GDCM was built (PS3.6 Table A-1).
    static const std::pair<const char*, const char*> kNewer[] = {
        {"1.2.840.10008.1.2.4.100", "MPEG2 Main Profile / Main Level"},
        {"1.2.840.10008.1.2.4.100.1", "Fragmentable MPEG2 Main Profile / Main Level"},
        {"1.2.840.10008.1.2.4.101", "MPEG2 Main Profile / High Level"},
        {"1.2.840.10008.1.2.4.102", "MPEG-4 AVC/H.264 High Profile"},
        {"1.2.840.10008.1.2.4.103", "MPEG-4 AVC/H.264 BD-compatible High Profile"},
        {"1.2.840.10008.1.2.4.104", "MPEG-4 AVC/H.264 High Profile For 2D Video"},
        {"1.2.840.10008.1.2.4.105", "MPEG-4 AVC/H.264 High Profile For 3D Video"},
        {"1.2.840.10008.1.2.4.106", "MPEG-4 AVC/H.264 Stereo High Profile"},
        {"1.2.840.10008.1.2.4.107", "HEVC/H.265 Main Profile"},
        {"1.2.840.10008.1.2.4.108", "HEVC/H.265 Main 10 Profile"},
        {"1.2.840.10008.1.2.4.110", "JPEG XL Lossless"},
        {"1.2.840.10008.1.2.4.111", "JPEG XL JPEG Recompression"},
        {"1.2.840.10008.1.2.4.112", "JPEG XL"},
        {"1.2.840.10008.1.2.4.201", "High-Throughput JPEG 2000 Lossless"},
        {"1.2.840.10008.1.2.4.202", "High-Throughput JPEG 2000 with RPCL Lossless"},
        {"1.2.840.10008.1.2.4.203", "High-Throughput JPEG 2000"},
        {"1.2.840.10008.1.2.4.204", "JPIP HTJ2K Referenced"},
        {"1.2.840.10008.1.2.4.205", "JPIP HTJ2K Referenced Deflate"},
        {"1.2.840.10008.1.2.8.1", "Deflated Image Frame Compression"},
        {"1.2.840.10008.1.2.7.1", "SMPTE ST 2110-20 Uncompressed Progressive Active Video"},
        {"1.2.840.10008.1.2.7.2", "SMPTE ST 2110-20 Uncompressed Interlaced Active Video"},
        {"1.2.840.10008.1.2.7.3", "SMPTE ST 2110-30 PCM Digital Audio"}};
    for (const auto& [known, name] : kNewer) {
        if (uid == known) return uid + " (" + name + ", which GDCM cannot read)";
    }
    return uid + " (unknown transfer syntax)";
}

std::string trim(const std::string& s) {
    const auto notSpace = [](char c) {
        return c != ' ' && c != '\0' && c != '\t' && c != '\r' && c != '\n';
    };
    const auto b = std::find_if(s.begin(), s.end(), notSpace);
    const auto e = std::find_if(s.rbegin(), s.rend(), notSpace).base();
    return b < e ? std::string(b, e) : std::string();
}

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

std::optional<double> parseDateTime(const std::string& text) {
    std::string t = trim(text);
    if (const std::size_t zone = t.find_first_of("+-"); zone != std::string::npos)
        t = t.substr(0, zone);
    if (t.size() < 8 ||
        !std::all_of(t.begin(), t.begin() + 8, [](char c) { return c >= '0' && c <= '9'; })) {
        return std::nullopt;
    }
    const int y = std::stoi(t.substr(0, 4)), m = std::stoi(t.substr(4, 2)),
              d = std::stoi(t.substr(6, 2));
    if (m < 1 || m > 12 || d < 1 || d > 31) return std::nullopt;
    // Days since 1970-01-01 of the proleptic Gregorian date (H. Hinnant's days_from_civil).
    const int yy = y - (m <= 2 ? 1 : 0);
    const int era = (yy >= 0 ? yy : yy - 399) / 400;
    const int yoe = yy - era * 400;
    const int doy = (153 * (m + (m > 2 ? -3 : 9)) + 2) / 5 + d - 1;
    const int doe = yoe * 365 + yoe / 4 - yoe / 100 + doy;
    const double days = era * 146097.0 + doe - 719468.0;
    double seconds = 0;
    if (t.size() > 8) {
        const auto time = parseTime(t.substr(8));
        if (!time) return std::nullopt;
        seconds = *time;
    }
    return days * 86400.0 + seconds;
}

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

FileGeometry geometryOf(const Header& h) {
    const std::string file = h.label();
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
    // A finite but absurd spacing or position (a 1e300 mm pixel) is refused here, before it
    // reaches the resampler's lattice arithmetic.
    try {
        for (std::size_t i = 0; i < 2; ++i) {
            palp::requireWithin(file + ": Pixel Spacing (0028,0030)[" + std::to_string(i) + "]",
                                ps[i] * 1e-3, bounds::kSpacing, {1e3, "mm"});
        }
        for (std::size_t i = 0; i < 3; ++i) {
            palp::requireWithin(
                file + ": Image Position (Patient) (0020,0032)[" + std::to_string(i) + "]",
                ipp[i] * 1e-3, bounds::kPosition, {1e3, "mm"});
        }
    } catch (const ValueError& e) {
        throw FormatError(e.what());
    }
    return g;
}

}  // namespace palp::volume::dicom
