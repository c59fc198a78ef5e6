#include "dicom/dicom_scan.h"

#include <gdcmScanner.h>
#include <gdcmTrace.h>

#include <algorithm>
#include <deque>
#include <map>
#include <set>

#include "dicom/dicom_frames.h"
#include "dicom/dicom_mosaic.h"
#include "dicom/dicom_slices.h"
#include "palp/base/error.h"

namespace palp::volume::dicom {

namespace fs = std::filesystem;

namespace {

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

}  // namespace

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

    const gdcm::Tag tags[] = {kSopClassUid,       kAcquisitionTime,
                              kContentTime,       kModality,
                              kSeriesDescription, kGantryTilt,
                              kSeriesUid,         kAcquisitionNumber,
                              kInstanceNumber,    kImagePosition,
                              kImageOrientation,  kTemporalPosition,
                              kSamplesPerPixel,   kPhotometric,
                              kNumberOfFrames,    kRows,
                              kColumns,           kPixelSpacing,
                              kBitsAllocated,     kRescaleIntercept,
                              kRescaleSlope,      kImageType,
                              kSliceThickness,    kSpacingBetweenSlices,
                              kSopInstanceUid,    kNumberOfTemporalPositions,
                              kDiffusionBValue,   kDiffusionGradientOrientation};
    // Only DICOM Part 10 files ("DICM" at byte 128) are read, and only those whose structure is
    // complete reach GDCM.
    std::vector<std::string> complete;
    std::map<std::string, Walk> walks;
    for (const std::string& f : files) {
        Walk w = walkFile(f);
        if (!w.isPart10) continue;
        if (w.complete) {
            complete.push_back(f);
            walks.emplace(f, std::move(w));
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
        const Walk& walk = walks.at(f);
        if (!scanner.IsKey(f.c_str())) {
            scan.unparsed.emplace_back(f, walk);
            continue;
        }
        Header h;
        h.path = f;
        for (const auto& [tag, value] : scanner.GetMapping(f.c_str())) {
            if (value) h.values[tag] = trim(value);
        }
        if (!walk.transferSyntax.empty()) h.values[kTransferSyntax] = walk.transferSyntax;
        h.pixelDataFits = walk.pixelDataFits;
        // A file GDCM parsed but that carries none of the tags every DICOM object has is not
        // DICOM for our purposes (GDCM accepts some raw data sets without preamble).
        if (!h.get(kSopClassUid) && !h.get(kSeriesUid) && !h.isImage()) continue;
        scan.headers.push_back(std::move(h));
    }
    return scan;
}

void checkTransferSyntax(const Header& h) {
    const std::string uid = h.text(kTransferSyntax);
    if (uid.empty() || gdcmKnowsTransferSyntax(uid)) return;
    throw FormatError(h.path.string() + ": expected a transfer syntax GDCM can decode, found " +
                      describeTransferSyntax(uid));
}

[[noreturn]] void throwNoDicom(const Scan& scan) {
    if (!scan.unparsed.empty()) {
        const auto& [file, walk] = scan.unparsed.front();
        const std::string more =
            scan.unparsed.size() > 1
                ? " (and " + std::to_string(scan.unparsed.size() - 1) + " more such files)"
                : std::string();
        const std::string uid = walk.transferSyntax;
        throw FormatError(file.string() + ": expected a DICOM file GDCM can read, found " +
                          (uid.empty() || !gdcmKnowsTransferSyntax(uid)
                               ? "one in transfer syntax " + describeTransferSyntax(uid)
                               : "one whose data set GDCM cannot parse (transfer syntax " +
                                     describeTransferSyntax(uid) + ")") +
                          more);
    }
    if (scan.fileCount == 0) {
        throw FormatError(scan.inputsName + ": expected DICOM files, found none (no files)");
    }
    throw FormatError(scan.inputsName + ": expected DICOM files, found none among " +
                      std::to_string(scan.fileCount) + " files");
}

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

namespace {

/// Positions and time points of a series with enhanced multi-frame files, counted over frames
/// as readDicom groups them; where readDicom would refuse the frames, the reason goes to
/// info.problem and the counts are those of the frames' positions. False when the frames cannot
/// be read (then the series is described by its files, and converting it gives the reason).
bool describeFrames(const SeriesGroup& g, DicomSeriesInfo& info) {
    std::deque<Header> store;
    std::vector<const Header*> frames;
    try {
        frames = expandFrames(g.images, store);
    } catch (const Error& e) {
        info.problem = e.what();
        return false;
    }
    info.frameCount = static_cast<int>(frames.size());
    try {
        checkFramesAgree(frames);
        const auto positions = framePositions("series " + g.uid, frames);
        info.positionCount = static_cast<int>(positions.size());
        info.timePointCount = static_cast<int>(positions.front().size());
        return true;
    } catch (const Error& e) {
        info.problem = e.what();
    }
    const auto n = normalOf(*frames.front());
    if (!n) return false;
    const auto groups = groupPositions(frames, *n, positionTolerance(*frames.front()));
    info.positionCount = static_cast<int>(groups.size());
    std::size_t most = 0;
    for (const auto& grp : groups) most = std::max(most, grp.size());
    info.timePointCount = info.frameCount % info.positionCount == 0
                              ? info.frameCount / info.positionCount
                              : static_cast<int>(most);
    return true;
}

}  // namespace

DicomSeriesInfo describeSeries(const SeriesGroup& g) {
    DicomSeriesInfo info;
    info.uid = g.uid;
    info.description = g.files.front()->text(kSeriesDescription);
    info.modality = g.files.front()->text(kModality);
    info.imageCount = static_cast<int>(g.images.size());
    info.frameCount = info.imageCount;
    for (const Header* h : g.files) info.files.push_back(h->path);
    if (g.images.empty()) {
        info.positionCount = 0;
        info.timePointCount = 0;
        return info;
    }
    if (hasMultiFrame(g.images) && describeFrames(g, info)) return info;
    info.frameCount = 0;
    for (const Header* h : g.images) info.frameCount += frameCountOf(*h);
    const auto n = normalOf(*g.images.front());
    if (!n) {
        info.positionCount = info.imageCount;
        return info;
    }
    const auto groups = groupPositions(g.images, *n, positionTolerance(*g.images.front()));
    if (groups.size() == 1 && isMosaic(*g.images.front())) {
        // Each mosaic is a whole volume: its slices are the positions, the files time points.
        const int slices = mosaicSliceCount(*g.images.front());
        info.positionCount = slices > 0 ? slices : 1;
        info.timePointCount = info.imageCount;
        return info;
    }
    info.positionCount = static_cast<int>(groups.size());
    std::size_t most = 0;
    for (const auto& grp : groups) most = std::max(most, grp.size());
    info.timePointCount = info.imageCount % info.positionCount == 0
                              ? info.imageCount / info.positionCount
                              : static_cast<int>(most);
    return info;
}

const SeriesGroup& chooseSeries(const Scan& scan, const std::vector<SeriesGroup>& groups,
                                const ReadOptions& options) {
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
                     "; choose one by its series UID:" + listSeries(groups));
}

std::string seriesName(const Scan& scan, const SeriesGroup& g) {
    const std::string desc = g.files.front()->text(kSeriesDescription);
    return desc.empty() ? scan.inputsName : scan.inputsName + " (series \"" + desc + "\")";
}

/// The DICOM series of @p files, with their damaged and unparsable files placed as
/// FoundScan::files says.
std::vector<FoundScan> findScans(const std::vector<fs::path>& files) {
    const Scan scan = scanHeaders(files);
    std::vector<FoundScan> out;
    std::map<std::string, std::size_t> byUid;            // series UID -> index in out
    std::map<fs::path, std::set<std::size_t>> byFolder;  // folder -> series with a file there
    for (const SeriesGroup& g : groupSeries(scan)) {
        FoundScan s;
        s.format = Format::Dicom;
        s.seriesUid = g.uid;
        s.description = g.files.front()->text(kSeriesDescription);
        s.modality = g.files.front()->text(kModality);
        s.imageCount = static_cast<int>(g.images.size());
        for (const Header* h : g.files) {
            s.files.push_back(h->path);
            byFolder[h->path.parent_path()].insert(out.size());
        }
        byUid[g.uid] = out.size();
        out.push_back(std::move(s));
    }
    // Files of no series: by UID when it was read, else by folder.
    std::map<std::pair<std::string, fs::path>, std::size_t> leftovers;
    const auto place = [&](const fs::path& file, const std::string& uid, bool damaged) {
        if (!uid.empty()) {
            if (const auto at = byUid.find(uid); at != byUid.end()) {
                out[at->second].files.push_back(file);
                return;
            }
        } else if (damaged) {
            // A damaged file whose series cannot be told taints every series beside it, as
            // load() of their folder refuses them all.
            if (const auto at = byFolder.find(file.parent_path()); at != byFolder.end()) {
                for (const std::size_t i : at->second) out[i].files.push_back(file);
                return;
            }
        }
        const auto key = std::make_pair(uid, uid.empty() ? file.parent_path() : fs::path());
        auto [slot, fresh] = leftovers.try_emplace(key, out.size());
        if (fresh) {
            FoundScan s;
            s.format = Format::Dicom;
            s.seriesUid = uid;
            s.unreadable = true;
            out.push_back(std::move(s));
            if (!uid.empty()) byUid[uid] = slot->second;
        }
        out[slot->second].files.push_back(file);
    };
    for (const auto& [file, walk] : scan.damaged) place(file, walk.seriesUid, true);
    for (const auto& [file, walk] : scan.unparsed) place(file, walk.seriesUid, false);
    for (FoundScan& s : out) std::sort(s.files.begin(), s.files.end());
    return out;
}

}  // namespace palp::volume::dicom
