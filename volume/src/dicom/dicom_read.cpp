// DICOM series reading through GDCM: a cheap header scan of every file (dicom_scan), series
// and time point selection from those headers (dicom_slices), then pixel decoding
// (dicom_pixels) of the chosen files only. Single-frame series, Siemens mosaics and enhanced
// multi-frame files (dicom_frames), one or several per series.
#include <gdcmImageReader.h>

#include <Eigen/Geometry>
#include <algorithm>
#include <deque>
#include <exception>
#include <map>
#include <memory>

#include "dicom/dicom_frames.h"
#include "dicom/dicom_header.h"
#include "dicom/dicom_mosaic.h"
#include "dicom/dicom_pixels.h"
#include "dicom/dicom_scan.h"
#include "dicom/dicom_series.h"
#include "dicom/dicom_slices.h"
#include "dicom/dicom_walk.h"
#include "lazy_stack.h"
#include "palp/base/error.h"
#include "palp/base/parallel.h"
#include "palp/volume/dicom.h"
#include "time_point.h"

namespace palp::volume {

namespace fs = std::filesystem;

namespace dicom {
namespace {

/// A series with enhanced multi-frame files (one file, or several: one per time point, or the
/// slices of a volume spread over files; single-frame files may join them): every frame is an
/// image with its own position, orientation, spacing, rescale and time keys; the frames must
/// agree in size, orientation and spacing and form positions x time points. Only the files
/// holding a frame of the chosen time point are decoded, one at a time.
SliceStack readFrameSeries(const std::vector<const Header*>& images, const std::string& name,
                           const std::string& uid, const std::vector<fs::path>& inputs,
                           const ReadOptions& options) {
    std::deque<Header> store;
    const std::vector<const Header*> frames = expandFrames(images, store);
    checkFramesAgree(frames);
    const auto positions = framePositions(name, frames);
    const int timePointCount = static_cast<int>(positions.front().size());
    const int timePoint = detail::chooseTimePoint(timePointCount, options, name);
    const Header& first = *frames.front();
    const int rows = first.integer(kRows, 0), cols = first.integer(kColumns, 0);
    checkMemory(name, cols, rows, positions.size(), options.maxSourceBytes);

    SliceStack stack;
    stack.slices.resize(positions.size());
    // The chosen frame of each position, by file, so that each file is decoded once.
    std::map<fs::path, std::vector<std::size_t>> byFile;
    for (std::size_t i = 0; i < positions.size(); ++i) {
        byFile[positions[i][static_cast<std::size_t>(std::max(timePoint, 0))]->path].push_back(i);
    }
    const double slope0 = first.number(kRescaleSlope).value_or(1.0);
    const double intercept0 = first.number(kRescaleIntercept).value_or(0.0);
    bool rescaleVaries = false;
    for (const auto& [path, slots] : byFile) {
        const auto chosen = [&](std::size_t slot) -> const Header& {
            return *positions[slot][static_cast<std::size_t>(std::max(timePoint, 0))];
        };
        const Header& fileHeader = chosen(slots.front());
        const int fileFrames = frameCountOf(fileHeader);
        gdcm::ImageReader reader;
        std::vector<char> buffer;
        if (fileFrames > 1) {
            // GDCM decodes every frame of a file at once: the whole file counts.
            checkMemory(name, cols, rows, static_cast<std::size_t>(fileFrames),
                        options.maxSourceBytes);
            decodeFile(fileHeader, fileFrames, reader, buffer);
        }
        for (const std::size_t slot : slots) {
            const Header& h = chosen(slot);
            Slice& s = stack.slices[slot];
            if (h.frame == 0) {
                decodeSlice(h, s);
            } else {
                const gdcm::PixelFormat& pf = reader.GetImage().GetPixelFormat();
                const std::size_t count =
                    static_cast<std::size_t>(rows) * static_cast<std::size_t>(cols);
                const double slope =
                    checkedSlope(h.label(), h.number(kRescaleSlope), h.text(kRescaleSlope));
                const double intercept = h.number(kRescaleIntercept).value_or(0.0);
                convertFrame(h.label(),
                             buffer.data() +
                                 static_cast<std::size_t>(h.frame - 1) * count * pf.GetPixelSize(),
                             pf, count, slope, intercept, s.values);
                s.cols = cols;
                s.rows = rows;
            }
            setGeometry(geometryOf(h), s);
            s.source = h.label();
            rescaleVaries = rescaleVaries || h.number(kRescaleSlope).value_or(1.0) != slope0 ||
                            h.number(kRescaleIntercept).value_or(0.0) != intercept0;
        }
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

std::vector<DicomSeriesInfo> scanSeries(const std::vector<fs::path>& inputs) {
    const Scan scan = scanHeaders(inputs);
    if (scan.headers.empty()) throwNoDicom(scan);
    std::vector<DicomSeriesInfo> out;
    for (const SeriesGroup& g : groupSeries(scan)) out.push_back(describeSeries(g));
    return out;
}

detail::LazySliceStack openSeries(const std::vector<fs::path>& inputs, const ReadOptions& options) {
    // The headers stay alive with the decoder, which reads the chosen files through them.
    const auto scanned = std::make_shared<const Scan>(scanHeaders(inputs));
    const Scan& scan = *scanned;
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
    }
    if (hasMultiFrame(series.images))
        return {readFrameSeries(series.images, name, series.uid, inputs, options), {}};
    const std::vector<const Header*>& images = series.images;
    const Header& first = *images.front();
    const FileGeometry firstGeometry = geometryOf(first);
    for (const Header* h : images) geometryOf(*h);  // every file must carry its geometry
    const Eigen::Vector3d normal =
        firstGeometry.rowCosine.cross(firstGeometry.columnCosine).normalized();
    std::vector<std::vector<const Header*>> positions = groupPositions(
        images, normal, 0.02 * std::min(firstGeometry.rowSpacing, firstGeometry.columnSpacing));
    std::size_t fewest = positions.front().size(), most = fewest;
    for (const auto& grp : positions) {
        fewest = std::min(fewest, grp.size());
        most = std::max(most, grp.size());
    }
    // A series whose positions hold different numbers of images is refused, unless a time point
    // was asked for that every position holds and the acquisition times show whole (a 4D
    // acquisition stopped early: its first volumes are complete).
    const bool partial = fewest != most;
    if (partial && (!options.timePoint || most < 2)) checkSameCount(name, positions, normal);
    const int timePointCount = static_cast<int>(most);
    const int timePoint = detail::chooseTimePoint(timePointCount, options, name);

    const TimeOrder order(images, positions);
    for (auto& grp : positions) order.sort(grp);
    if (partial) checkPartialTimePoint(name, positions, static_cast<std::size_t>(timePoint));
    checkDiffusionPerTimePoint(name, positions, order);
    std::vector<const Header*> chosen;
    for (const auto& grp : positions)
        chosen.push_back(grp[static_cast<std::size_t>(std::max(timePoint, 0))]);

    if (isMosaic(first)) {
        return {readMosaicSeries(images, chosen, name, series.uid, inputs, options, timePoint,
                                 timePointCount),
                {}};
    }

    // Refuse before decoding anything that would not fit the memory budget.
    checkMemory(name, first.integer(kColumns, 0), first.integer(kRows, 0), chosen.size(),
                options.maxSourceBytes);

    detail::LazySliceStack lazy;
    SliceStack& stack = lazy.stack;
    stack.slices.resize(chosen.size());
    for (std::size_t i = 0; i < chosen.size(); ++i) {
        Slice& s = stack.slices[i];
        s.cols = chosen[i]->integer(kColumns, 0);
        s.rows = chosen[i]->integer(kRows, 0);
        s.source = chosen[i]->path.string();
        setGeometry(geometryOf(*chosen[i]), s);
    }
    bool rescaleVaries = false;
    const double slope0 = first.number(kRescaleSlope).value_or(1.0);
    const double intercept0 = first.number(kRescaleIntercept).value_or(0.0);
    for (const Header* h : chosen) {
        rescaleVaries = rescaleVaries || h->number(kRescaleSlope).value_or(1.0) != slope0 ||
                        h->number(kRescaleIntercept).value_or(0.0) != intercept0;
    }
    fillInfo(stack.info, first, inputs, series.uid, chosen.size(), timePoint, timePointCount,
             rescaleVaries);
    // One GDCM reader per call, so files may be decoded from several threads at once.
    lazy.decode = [scanned, chosen](std::size_t i, Slice& slice) {
        return decodeSlice(*chosen[i], slice);
    };
    return lazy;
}

SliceStack readSeries(const std::vector<fs::path>& inputs, const ReadOptions& options) {
    detail::LazySliceStack lazy = openSeries(inputs, options);
    if (!lazy.decode) return std::move(lazy.stack);
    std::vector<Slice>& slices = lazy.stack.slices;
    // Files decoded in parallel; when several fail, the first file's error is reported, as a
    // serial loop would.
    std::vector<std::exception_ptr> errors(slices.size());
    palp::parallelForEach(
        std::size_t{0}, slices.size(),
        [&](std::size_t i) {
            try {
                lazy.decode(i, slices[i]);
            } catch (...) {
                errors[i] = std::current_exception();
            }
        },
        std::size_t{1});
    for (const std::exception_ptr& e : errors)
        if (e) std::rethrow_exception(e);
    return std::move(lazy.stack);
}

}  // namespace dicom
}  // namespace palp::volume
