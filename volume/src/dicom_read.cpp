// DICOM series reading through GDCM: a cheap header scan of every file (dicom_scan), series
// and time point selection from those headers (dicom_slices), then pixel decoding
// (dicom_pixels) of the chosen files only. Single-frame series and enhanced multi-frame files.
#include <gdcmImageReader.h>
#include <gdcmSequenceOfItems.h>

#include <algorithm>
#include <functional>

#include "dicom_header.h"
#include "dicom_mosaic.h"
#include "dicom_pixels.h"
#include "dicom_scan.h"
#include "dicom_slices.h"
#include "dicom_walk.h"
#include "palp/base/error.h"
#include "palp/volume/dicom.h"
#include "time_point.h"

namespace palp::volume {

namespace fs = std::filesystem;

namespace dicom {
namespace {

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

/// One enhanced multi-frame file: every frame's own position from the per-frame functional
/// groups (so uneven spacing is kept exactly), orientation, spacing and rescale from the
/// per-frame or shared groups. Repeated positions are time points in frame order.
SliceStack readMultiFrame(const Header& h, int frames, const std::string& name,
                          const std::string& uid, const std::vector<fs::path>& inputs,
                          const ReadOptions& options) {
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
    const int timePoint = detail::chooseTimePoint(timePointCount, options, name);

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

/// A series of Siemens mosaics: each file is one whole volume (one time point), so every file
/// must be a mosaic and all must share one position; @p chosen holds the time point's file.
SliceStack readMosaicSeries(const std::vector<const Header*>& images,
                            const std::vector<const Header*>& chosen, const std::string& name,
                            const std::string& uid, const std::vector<fs::path>& inputs,
                            const ReadOptions& options, int timePoint, int timePointCount) {
    for (const Header* h : images) {
        if (!isMosaic(*h)) {
            throw FormatError(h->path.string() + ": expected a MOSAIC image like " +
                              images.front()->path.string() + " (Image Type (0008,0008) '" +
                              images.front()->text(kImageType) + "'), found Image Type '" +
                              h->text(kImageType) + "'");
        }
    }
    if (chosen.size() != 1) {
        throw FormatError(name +
                          ": expected the mosaics of a series at one position (each holds "
                          "a whole volume), found " +
                          std::to_string(chosen.size()) + " positions (e.g. " +
                          chosen.back()->path.string() + ")");
    }
    const Header& h = *chosen.front();
    checkMemory(name, h.integer(kColumns, 0), h.integer(kRows, 0), 1, options.maxSourceBytes);
    SliceStack stack;
    std::array<std::int64_t, 3> dims{};
    stack.slices = readMosaic(h, dims);
    fillInfo(stack.info, h, inputs, uid, stack.slices.size(), timePoint, timePointCount, false);
    stack.info.originalDims = dims;
    return stack;
}

}  // namespace
}  // namespace dicom

using namespace dicom;

std::vector<DicomSeriesInfo> scanDicom(const std::vector<fs::path>& inputs) {
    const Scan scan = scanHeaders(inputs);
    if (scan.headers.empty()) throwNoDicom(scan);
    std::vector<DicomSeriesInfo> out;
    for (const SeriesGroup& g : groupSeries(scan)) out.push_back(describeSeries(g));
    return out;
}

SliceStack readDicom(const std::vector<fs::path>& inputs, const ReadOptions& options) {
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
    for (const auto& [file, walk] : scan.unparsed) {
        // A file of this series GDCM cannot parse would otherwise be left out silently.
        if (walk.seriesUid == series.uid) {
            throw FormatError(file.string() + ": expected an image of series " + series.uid +
                              " GDCM can read, found one in transfer syntax " +
                              describeTransferSyntax(walk.transferSyntax) +
                              " whose data set GDCM cannot parse");
        }
    }
    for (const Header* h : series.images) checkTransferSyntax(*h);

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
    const int timePoint = detail::chooseTimePoint(timePointCount, options, name);

    const TimeOrder order(images);
    std::vector<const Header*> chosen;
    for (auto& grp : positions) {
        std::stable_sort(grp.begin(), grp.end(), [&](const Header* a, const Header* b) {
            const auto ka = order.key(*a), kb = order.key(*b);
            return ka != kb ? ka < kb : a->path < b->path;
        });
        chosen.push_back(grp[static_cast<std::size_t>(std::max(timePoint, 0))]);
    }

    if (isMosaic(first))
        return readMosaicSeries(images, chosen, name, series.uid, inputs, options, timePoint,
                                timePointCount);

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
