#include "dicom/dicom_frames.h"

#include <gdcmReader.h>
#include <gdcmSequenceOfItems.h>

#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <set>

#include "dicom/dicom_element.h"
#include "palp/base/error.h"

namespace palp::volume::dicom {

namespace {

const gdcm::Tag kSharedGroups(0x5200, 0x9229);
const gdcm::Tag kPerFrameGroups(0x5200, 0x9230);
const gdcm::Tag kPixelMeasuresSequence(0x0028, 0x9110);
const gdcm::Tag kFrameContentSequence(0x0020, 0x9111);
const gdcm::Tag kPlanePositionSequence(0x0020, 0x9113);
const gdcm::Tag kPlaneOrientationSequence(0x0020, 0x9116);
const gdcm::Tag kValueTransformSequence(0x0028, 0x9145);

/// The value of @p t in @p ds as palp keeps values: trimmed text, or for UL values (binary in
/// the file, read by their VR: see numbersOf) the decimal numbers separated by '\'.
std::optional<std::string> elementValue(const gdcm::DataSet& ds, const gdcm::Tag& t, bool ul) {
    if (!ds.FindDataElement(t)) return std::nullopt;
    const gdcm::DataElement& de = ds.GetDataElement(t);
    if (ul) {
        const ElementNumbers n = numbersOf(de, gdcm::VR::UL);
        if (n.values.empty()) return std::nullopt;
        std::string out;
        for (const double v : n.values) {
            char buf[32];
            std::snprintf(buf, sizeof buf, "%.10g", v);
            out += (out.empty() ? "" : "\\") + std::string(buf);
        }
        return out;
    }
    const gdcm::ByteValue* bv = de.GetByteValue();
    if (!bv || !bv->GetPointer() || bv->GetLength() == 0) return std::nullopt;
    std::string s = trim(std::string(bv->GetPointer(), bv->GetLength()));
    if (s.empty()) return std::nullopt;
    return s;
}

/// The first item of the sequence @p sequence in @p group, if there is one.
const gdcm::DataSet* firstItem(const gdcm::DataSet& group, const gdcm::Tag& sequence,
                               gdcm::SmartPointer<gdcm::SequenceOfItems>& holder) {
    if (!group.FindDataElement(sequence)) return nullptr;
    holder = group.GetDataElement(sequence).GetValueAsSQ();
    if (!holder || holder->GetNumberOfItems() == 0) return nullptr;
    return &holder->GetItem(1).GetNestedDataSet();
}

/// Copies the values palp reads from one functional group item into @p h.
void applyFunctionalGroup(const gdcm::DataSet& group, Header& h) {
    struct Wanted {
        gdcm::Tag sequence, tag;
        bool ul;
    };
    static const Wanted wanted[] = {{kPixelMeasuresSequence, kPixelSpacing, false},
                                    {kPixelMeasuresSequence, kSliceThickness, false},
                                    {kPixelMeasuresSequence, kSpacingBetweenSlices, false},
                                    {kPlanePositionSequence, kImagePosition, false},
                                    {kPlaneOrientationSequence, kImageOrientation, false},
                                    {kValueTransformSequence, kRescaleSlope, false},
                                    {kValueTransformSequence, kRescaleIntercept, false},
                                    {kFrameContentSequence, kTemporalPositionIndex, true},
                                    {kFrameContentSequence, kDimensionIndexValues, true},
                                    {kFrameContentSequence, kFrameAcquisitionDateTime, false}};
    for (const Wanted& w : wanted) {
        gdcm::SmartPointer<gdcm::SequenceOfItems> holder;
        const gdcm::DataSet* item = firstItem(group, w.sequence, holder);
        if (!item) continue;
        if (auto v = elementValue(*item, w.tag, w.ul)) h.values[w.tag] = *v;
    }
}

std::string vecText(const Eigen::Vector3d& v) {
    char buf[96];
    std::snprintf(buf, sizeof buf, "(%.6g, %.6g, %.6g)", v.x(), v.y(), v.z());
    return buf;
}

std::string keyText(const std::vector<double>& key) {
    std::string s;
    for (double v : key) {
        char buf[32];
        std::snprintf(buf, sizeof buf, "%.10g", v);
        s += (s.empty() ? "" : ", ") + std::string(buf);
    }
    return s;
}

}  // namespace

int frameCountOf(const Header& h) { return h.integer(kNumberOfFrames, 1); }

std::vector<Header> frameHeaders(const Header& h, const gdcm::DataSet& ds) {
    const std::string file = h.path.string();
    const int frames = frameCountOf(h);
    if (!ds.FindDataElement(kPerFrameGroups)) {
        throw FormatError(
            file +
            ": expected a Per-frame Functional Groups Sequence (5200,9230) giving each of the " +
            std::to_string(frames) +
            " frames its position, found none (legacy multi-frame images are not supported)");
    }
    Header base = h;
    base.frame = 0;
    {
        gdcm::SmartPointer<gdcm::SequenceOfItems> holder;
        if (const gdcm::DataSet* shared = firstItem(ds, kSharedGroups, holder))
            applyFunctionalGroup(*shared, base);
    }
    const auto perFrame = ds.GetDataElement(kPerFrameGroups).GetValueAsSQ();
    const std::size_t items = perFrame ? perFrame->GetNumberOfItems() : 0;
    if (items != static_cast<std::size_t>(frames)) {
        throw FormatError(file + ": expected " + std::to_string(frames) +
                          " items in the Per-frame Functional Groups Sequence (5200,9230), found " +
                          std::to_string(items));
    }
    std::vector<Header> out(items, base);
    for (std::size_t k = 0; k < items; ++k) {
        applyFunctionalGroup(perFrame->GetItem(k + 1).GetNestedDataSet(), out[k]);
        out[k].frame = static_cast<int>(k + 1);
    }
    return out;
}

std::vector<Header> readFrameHeaders(const Header& h) {
    gdcm::Reader reader;
    reader.SetFileName(h.path.c_str());
    const std::set<gdcm::Tag> skip{kPixelData};
    if (!reader.ReadUpToTag(kPixelData, skip)) {
        throw FormatError(h.path.string() +
                          ": expected a readable enhanced multi-frame DICOM header, found one "
                          "GDCM cannot parse");
    }
    return frameHeaders(h, reader.GetFile().GetDataSet());
}

bool hasMultiFrame(const std::vector<const Header*>& images) {
    return std::any_of(images.begin(), images.end(),
                       [](const Header* h) { return frameCountOf(*h) > 1; });
}

std::vector<const Header*> expandFrames(const std::vector<const Header*>& images,
                                        std::deque<Header>& store) {
    std::vector<const Header*> out;
    for (const Header* h : images) {
        if (frameCountOf(*h) <= 1) {
            out.push_back(h);
            continue;
        }
        for (Header& f : readFrameHeaders(*h)) {
            store.push_back(std::move(f));
            out.push_back(&store.back());
        }
    }
    return out;
}

void checkFramesAgree(const std::vector<const Header*>& frames) {
    if (frames.empty()) return;
    const Header& first = *frames.front();
    const FileGeometry g0 = geometryOf(first);
    const int cols0 = first.integer(kColumns, 0), rows0 = first.integer(kRows, 0);
    for (const Header* h : frames) {
        const int cols = h->integer(kColumns, 0), rows = h->integer(kRows, 0);
        if (cols != cols0 || rows != rows0) {
            throw FormatError(h->label() + ": expected " + std::to_string(cols0) + "x" +
                              std::to_string(rows0) + " pixels (Columns x Rows) like " +
                              first.label() + ", found " + std::to_string(cols) + "x" +
                              std::to_string(rows));
        }
        const FileGeometry g = geometryOf(*h);
        if ((g.rowCosine - g0.rowCosine).norm() > 1e-4 ||
            (g.columnCosine - g0.columnCosine).norm() > 1e-4) {
            throw FormatError(h->label() + ": expected the orientation of " + first.label() +
                              " (row " + vecText(g0.rowCosine) + ", column " +
                              vecText(g0.columnCosine) + "), found row " + vecText(g.rowCosine) +
                              ", column " + vecText(g.columnCosine));
        }
        if (std::abs(g.rowSpacing - g0.rowSpacing) > 1e-4 * g0.rowSpacing ||
            std::abs(g.columnSpacing - g0.columnSpacing) > 1e-4 * g0.columnSpacing) {
            throw FormatError(h->label() + ": expected the Pixel Spacing (0028,0030) of " +
                              first.label() + " ('" + first.text(kPixelSpacing) + "'), found '" +
                              h->text(kPixelSpacing) + "'");
        }
    }
}

std::vector<std::vector<const Header*>> framePositions(const std::string& name,
                                                       const std::vector<const Header*>& frames) {
    const FileGeometry g0 = geometryOf(*frames.front());
    for (const Header* h : frames) geometryOf(*h);  // every frame must carry its geometry
    const Eigen::Vector3d normal = g0.rowCosine.cross(g0.columnCosine).normalized();
    const double tolMm = 0.02 * std::min(g0.rowSpacing, g0.columnSpacing);
    std::vector<std::vector<const Header*>> positions = groupPositions(frames, normal, tolMm);
    const TimeOrder order(frames, positions);
    for (auto& grp : positions) {
        order.sort(grp);
        for (std::size_t i = 1; i < grp.size(); ++i) {
            const Header& a = *grp[i - 1];
            const Header& b = *grp[i];
            const std::vector<double> key = order.key(a);
            if (key.empty() || key != order.key(b)) continue;
            if (a.path == b.path && !order.frameKeys()) continue;  // frame order within a file
            throw FormatError(name +
                              ": expected one frame per time point at each slice position, found " +
                              a.label() + " and " + b.label() + " at the same position (" +
                              std::to_string(positionOf(a)->dot(normal)) +
                              " mm along the normal) with the same time keys (" +
                              order.describe(a) + "); a duplicated file or frame");
        }
        for (std::size_t i = 1; order.useTemporalIndex && i < grp.size(); ++i) {
            if (*grp[i]->number(kTemporalPositionIndex) ==
                *grp[i - 1]->number(kTemporalPositionIndex)) {
                throw FormatError(
                    name +
                    ": expected one frame per Temporal Position Index (0020,9128) "
                    "at each slice position, found " +
                    grp[i - 1]->label() + " and " + grp[i]->label() + " both with index " +
                    keyText({*grp[i]->number(kTemporalPositionIndex)}) + " at " +
                    std::to_string(positionOf(*grp[i])->dot(normal)) + " mm along the normal");
            }
        }
    }
    checkSameCount(name, positions, normal);
    if (!order.useTemporalIndex) return positions;

    // Temporal Position Index: one value per time point, the same at every position, 1..T.
    const std::size_t timePoints = positions.front().size();
    std::vector<double> firstIndices;
    for (const Header* h : positions.front())
        firstIndices.push_back(*h->number(kTemporalPositionIndex));
    for (const auto& grp : positions) {
        std::vector<double> indices;
        for (const Header* h : grp) indices.push_back(*h->number(kTemporalPositionIndex));
        if (indices != firstIndices) {
            throw FormatError(name + ": expected the Temporal Position Index (0020,9128) values " +
                              keyText(firstIndices) + " of " + positions.front().front()->label() +
                              "'s position at every slice position, found " + keyText(indices) +
                              " at that of " + grp.front()->label());
        }
    }
    std::vector<double> expected(timePoints);
    for (std::size_t i = 0; i < timePoints; ++i) expected[i] = static_cast<double>(i + 1);
    if (firstIndices != expected) {
        std::string missing;
        int listed = 0;
        for (double v = 1; v <= firstIndices.back() && listed < 10; ++v) {
            if (std::binary_search(firstIndices.begin(), firstIndices.end(), v)) continue;
            missing += (missing.empty() ? "" : ", ") + keyText({v});
            if (++listed == 10) missing += ", ...";
        }
        throw FormatError(
            name + ": expected Temporal Position Index (0020,9128) values 1 to " +
            std::to_string(timePoints) + " (one per time point), found " + keyText(firstIndices) +
            (missing.empty() ? std::string()
                             : " (index " + missing + " missing: the series lacks time points)"));
    }
    const auto declared = frames.front()->number(kNumberOfTemporalPositions);
    if (declared && *declared != static_cast<double>(timePoints)) {
        throw FormatError(name + ": expected " + keyText({*declared}) +
                          " time points as Number of Temporal Positions (0020,0105) of " +
                          frames.front()->path.string() + " says, found " +
                          std::to_string(timePoints));
    }
    return positions;
}

}  // namespace palp::volume::dicom
