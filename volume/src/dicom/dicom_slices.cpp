#include "dicom/dicom_slices.h"

#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <map>
#include <utility>

#include "dicom/dicom_ge.h"
#include "palp/base/error.h"

namespace palp::volume::dicom {

namespace fs = std::filesystem;

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

void checkSameCount(const std::string& name,
                    const std::vector<std::vector<const Header*>>& positions,
                    const Eigen::Vector3d& normal) {
    // The count most positions have is the expected one; the first position that differs is
    // named (the first may be the odd one).
    std::map<std::size_t, std::size_t> positionsWith;
    for (const auto& grp : positions) ++positionsWith[grp.size()];
    if (positionsWith.size() <= 1) return;
    const auto common = std::max_element(
        positionsWith.begin(), positionsWith.end(), [](const auto& a, const auto& b) {
            // On a tie the larger count: images go missing more often than they multiply.
            return a.second != b.second ? a.second < b.second : a.first < b.first;
        });
    for (const auto& grp : positions) {
        if (grp.size() == common->first) continue;
        const auto p = positionOf(*grp.front());
        const std::string at =
            p ? " at position " + std::to_string(p->dot(normal)) + " mm along the normal"
              : std::string(" at an image without a position");
        throw ValueError(name + ": expected the same number of images at every slice position (" +
                         std::to_string(common->first) + " at " + std::to_string(common->second) +
                         " of " + std::to_string(positions.size()) + " positions), found " +
                         std::to_string(grp.size()) + at + " (e.g. " + grp.front()->label() +
                         "); the series is incomplete or mixes acquisitions");
    }
}

TimeOrder::TimeOrder(const std::vector<const Header*>& images,
                     const std::vector<std::vector<const Header*>>& positions) {
    bool first = true;
    for (const Header* h : images) {
        useTemporalIndex = useTemporalIndex && h->number(kTemporalPositionIndex).has_value();
        useFrameTime = useFrameTime && parseDateTime(h->text(kFrameAcquisitionDateTime));
        const auto dims = h->get(kDimensionIndexValues)
                              ? parseNumbers(h->text(kDimensionIndexValues))
                              : std::nullopt;
        useDimensionIndex = useDimensionIndex && dims && (first || dims->size() == dimensionCount);
        if (dims && first) dimensionCount = dims->size();
        useTemporal = useTemporal && h->number(kTemporalPosition).has_value();
        useAcqNumber = useAcqNumber && h->number(kAcquisitionNumber).has_value();
        useAcqTime = useAcqTime && parseTime(h->text(kAcquisitionTime)).has_value();
        useContentTime = useContentTime && parseTime(h->text(kContentTime)).has_value();
        useInstance = useInstance && h->number(kInstanceNumber).has_value();
        first = false;
    }
    if (images.empty()) {
        useTemporalIndex = useFrameTime = useDimensionIndex = false;
        return;
    }
    // A frame-level key with one value over the whole series tells nothing (Canon and some
    // Siemens XA files give every volume Temporal Position Index 1): it is not used, so that it
    // neither makes frames look like duplicates nor hides the files' own keys.
    const auto varies = [&](const gdcm::Tag& t) {
        return std::any_of(images.begin(), images.end(),
                           [&](const Header* h) { return h->text(t) != images.front()->text(t); });
    };
    useTemporalIndex = useTemporalIndex && varies(kTemporalPositionIndex);
    useFrameTime = useFrameTime && varies(kFrameAcquisitionDateTime);
    useDimensionIndex = useDimensionIndex && varies(kDimensionIndexValues);
    instanceDecides =
        useInstance &&
        std::all_of(positions.begin(), positions.end(), [](const std::vector<const Header*>& grp) {
            std::vector<double> n;
            for (const Header* h : grp) n.push_back(*h->number(kInstanceNumber));
            std::sort(n.begin(), n.end());
            return std::adjacent_find(n.begin(), n.end()) == n.end();
        });
    if (instanceDecides) useAcqNumber = useAcqTime = useContentTime = false;
}

std::vector<double> TimeOrder::key(const Header& h) const {
    std::vector<double> k;
    if (useTemporalIndex) k.push_back(*h.number(kTemporalPositionIndex));
    if (useFrameTime) k.push_back(*parseDateTime(h.text(kFrameAcquisitionDateTime)));
    if (useDimensionIndex) {
        const auto dims = parseNumbers(h.text(kDimensionIndexValues));
        k.insert(k.end(), dims->begin(), dims->end());
    }
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

std::string TimeOrder::describe(const Header& h) const {
    std::string s;
    const auto add = [&](bool use, const char* name, const gdcm::Tag& t) {
        if (use) s += (s.empty() ? "" : ", ") + std::string(name) + " " + h.text(t);
    };
    add(useTemporalIndex, "Temporal Position Index", kTemporalPositionIndex);
    add(useFrameTime, "Frame Acquisition DateTime", kFrameAcquisitionDateTime);
    add(useDimensionIndex, "Dimension Index Values", kDimensionIndexValues);
    add(useTemporal, "Temporal Position Identifier", kTemporalPosition);
    add(useAcqNumber, "Acquisition Number", kAcquisitionNumber);
    add(useAcqTime, "Acquisition Time", kAcquisitionTime);
    add(!useAcqTime && useContentTime, "Content Time", kContentTime);
    add(useInstance, "Instance Number", kInstanceNumber);
    return s;
}

void TimeOrder::sort(std::vector<const Header*>& images) const {
    std::vector<std::pair<std::vector<double>, const Header*>> keyed;
    keyed.reserve(images.size());
    for (const Header* h : images) keyed.emplace_back(key(*h), h);
    std::stable_sort(keyed.begin(), keyed.end(), [](const auto& a, const auto& b) {
        if (a.first != b.first) return a.first < b.first;
        if (a.second->path != b.second->path) return a.second->path < b.second->path;
        return a.second->frame < b.second->frame;
    });
    for (std::size_t i = 0; i < images.size(); ++i) images[i] = keyed[i].second;
}

namespace {

std::string numberText(double v) {
    char buf[32];
    std::snprintf(buf, sizeof buf, "%.6g", v);
    return buf;
}

}  // namespace

void checkDiffusionPerTimePoint(const std::string& name,
                                const std::vector<std::vector<const Header*>>& positions,
                                const TimeOrder& order) {
    const auto all = [&](const gdcm::Tag& t, std::size_t count) {
        for (const auto& grp : positions) {
            for (const Header* h : grp) {
                const std::string* v = h->get(t);
                const auto n = v ? parseNumbers(*v) : std::nullopt;
                if (!n || n->size() != count) return false;
            }
        }
        return !positions.empty();
    };
    if (!all(kDiffusionBValue, 1)) return;
    const bool gradients = all(kDiffusionGradientOrientation, 3);
    std::size_t timePoints = 0;
    for (const auto& grp : positions) timePoints = std::max(timePoints, grp.size());
    for (std::size_t t = 0; t < timePoints; ++t) {
        const Header* ref = nullptr;
        for (const auto& grp : positions) {
            if (t >= grp.size()) continue;
            const Header* h = grp[t];
            if (!ref) {
                ref = h;
                continue;
            }
            const double b0 = *ref->number(kDiffusionBValue), b = *h->number(kDiffusionBValue);
            bool same = std::abs(b - b0) <= 1e-3;
            if (same && gradients) {
                const auto g0 = *parseNumbers(ref->text(kDiffusionGradientOrientation));
                const auto g = *parseNumbers(h->text(kDiffusionGradientOrientation));
                for (std::size_t i = 0; i < 3; ++i) same = same && std::abs(g[i] - g0[i]) <= 1e-4;
            }
            if (same) continue;
            const auto weighting = [&](const Header& x) {
                std::string w = "b = " + numberText(*x.number(kDiffusionBValue)) + " s/mm^2";
                if (gradients) w += ", gradient (" + x.text(kDiffusionGradientOrientation) + ")";
                return w;
            };
            throw ValueError(name + ": expected one diffusion weighting per time point, found " +
                             weighting(*ref) + " in " + ref->label() + " and " + weighting(*h) +
                             " in " + h->label() + " at time point " + std::to_string(t) +
                             " (images ordered by " + order.describe(*h) +
                             "); the order of the images in time cannot be told from their "
                             "keys");
        }
    }
}

void checkPartialTimePoint(const std::string& name,
                           const std::vector<std::vector<const Header*>>& positions,
                           std::size_t t) {
    const auto timeOf = [](const Header& h) {
        const auto a = parseTime(h.text(kAcquisitionTime));
        return a ? a : parseTime(h.text(kContentTime));
    };
    bool allTimes = true, allInstances = true;
    for (const auto& grp : positions) {
        if (grp.size() <= t) {
            throw ValueError(name + ": expected time point " + std::to_string(t) +
                             " at every slice position, found " + std::to_string(grp.size()) +
                             " images at that of " + grp.front()->label() +
                             " (the series is incomplete)");
        }
        for (const Header* h : grp) {
            allTimes = allTimes && timeOf(*h).has_value();
            allInstances = allInstances && h->number(kInstanceNumber).has_value();
        }
    }
    if (!allTimes && !allInstances) {
        throw ValueError(name +
                         ": expected Acquisition Time (0008,0032), Content Time (0008,0033) or "
                         "Instance Number (0020,0013) in every image of a series whose slice "
                         "positions hold different numbers of images, to tell its complete time "
                         "points, found neither in all");
    }
    // When each image was acquired, as far as the tags tell: its time, then its instance number
    // (GE gives a whole series one Acquisition Time and numbers volume after volume).
    const auto when = [&](const Header& h) {
        return std::make_pair(allTimes ? *timeOf(h) : 0.0,
                              allInstances ? *h.number(kInstanceNumber) : 0.0);
    };
    // The latest image of rank k must precede the earliest of rank k + 1, for k = t - 1 and t.
    for (std::size_t k = t > 0 ? t - 1 : 0; k <= t; ++k) {
        const Header *latest = nullptr, *earliest = nullptr;
        for (const auto& grp : positions) {
            if (!latest || when(*grp[k]) > when(*latest)) latest = grp[k];
            if (grp.size() > k + 1 && (!earliest || when(*grp[k + 1]) < when(*earliest)))
                earliest = grp[k + 1];
        }
        if (earliest && !(when(*latest) < when(*earliest))) {
            throw ValueError(name + ": expected the images of time point " + std::to_string(k) +
                             " acquired before those of time point " + std::to_string(k + 1) +
                             " (by acquisition time, then instance number) in a series whose "
                             "slice positions hold different numbers of images, found " +
                             latest->label() + " (time point " + std::to_string(k) +
                             ") not before " + earliest->label() + " (time point " +
                             std::to_string(k + 1) +
                             "); an image is missing within the series, or the tags cannot "
                             "tell");
        }
    }
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
    if (info.modality == "MR") info.phaseEncodingPolarityGE = gePhaseEncodingPolarity(first.path);
}

}  // namespace palp::volume::dicom
