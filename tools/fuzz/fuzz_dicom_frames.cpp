// libFuzzer target: palp's grouping of enhanced multi-frame DICOM frames. The input describes
// one to three enhanced files (size, frame count, shared and per-frame functional groups:
// position, orientation, spacing, rescale, Temporal Position Index, Dimension Index Values,
// Frame Acquisition DateTime), each value either well formed (a position on a lattice, one of a
// few orientations) or raw bytes from the input. The data sets are built in memory (GDCM's
// parser is not what is fuzzed) and go through frameHeaders, checkFramesAgree, framePositions
// and chooseTimePoint as readDicom takes them. What is accepted must hold every frame exactly
// once, the same number at every position, positions in increasing order along the normal and
// each position's frames in time order.
// Any palp::Error is an accepted outcome; crashes, sanitizer reports, leaks and other
// exceptions are findings.
#include <gdcmDataElement.h>
#include <gdcmDataSet.h>
#include <gdcmSequenceOfItems.h>

#include <Eigen/Geometry>
#include <cstddef>
#include <cstdint>
#include <deque>
#include <functional>
#include <set>
#include <string>
#include <vector>

#include "dicom/dicom_frames.h"
#include "dicom/dicom_header.h"
#include "dicom/dicom_slices.h"
#include "palp/base/error.h"
#include "time_point.h"

namespace {

using namespace palp::volume::dicom;

/// Reads the fuzz input byte by byte; zeros once it is used up.
struct Bytes {
    const std::uint8_t* data;
    std::size_t size, at = 0;
    std::uint8_t next() { return at < size ? data[at++] : 0; }
    std::string raw() {
        const std::size_t n = next() % 24;
        std::string s;
        for (std::size_t i = 0; i < n; ++i) s.push_back(static_cast<char>(next()));
        return s;
    }
};

void put(gdcm::DataSet& ds, const gdcm::Tag& t, gdcm::VR vr, std::string v) {
    if (v.size() % 2) v.push_back(' ');
    gdcm::DataElement de(t);
    de.SetVR(vr);
    de.SetByteValue(v.data(), static_cast<std::uint32_t>(v.size()));
    ds.Replace(de);
}

void putItem(gdcm::DataSet& ds, std::uint16_t g, std::uint16_t e,
             const std::function<void(gdcm::DataSet&)>& fill) {
    gdcm::SmartPointer<gdcm::SequenceOfItems> sq = new gdcm::SequenceOfItems;
    gdcm::Item item;
    fill(item.GetNestedDataSet());
    sq->AddItem(item);
    gdcm::DataElement de(gdcm::Tag(g, e));
    de.SetVR(gdcm::VR::SQ);
    de.SetValue(*sq);
    ds.Replace(de);
}

const char* const kOrientations[] = {"1\\0\\0\\0\\1\\0", "0.6\\0.8\\0\\0\\0\\1",
                                     "1\\0\\0\\0\\0.9999\\0.0141", "0\\1\\0\\0\\0\\-1"};

std::string text(Bytes& in, const std::string& wellFormed) {
    return in.next() % 8 == 0 ? in.raw() : wellFormed;
}

std::string positionText(Bytes& in) {
    // Slices 2 mm apart along z, a few in-plane offsets and small jitters.
    const int slice = in.next() % 6;
    const double jitter = (in.next() % 5) * 0.01;
    const double x = -10 + (in.next() % 3) * 0.5;
    return text(in, std::to_string(x) + "\\4.5\\" + std::to_string(slice * 2.0 + jitter));
}

void fillFrameContent(Bytes& in, gdcm::DataSet& s, std::uint8_t flags) {
    if (flags & 1) {
        const std::uint32_t index = 1 + in.next() % 5;
        put(s, kTemporalPositionIndex, gdcm::VR::UL,
            std::string(reinterpret_cast<const char*>(&index), 4));
    }
    if (flags & 2) {
        const std::uint32_t dims[2] = {in.next() % 4u, in.next() % 4u};
        put(s, kDimensionIndexValues, gdcm::VR::UL,
            std::string(reinterpret_cast<const char*>(dims), (flags & 4) ? 8 : 4));
    }
    if (flags & 8) {
        put(s, kFrameAcquisitionDateTime, gdcm::VR::DT,
            text(in, "20250301120" + std::to_string(10 + in.next() % 40) + ".5"));
    }
}

/// One enhanced file's header and data set, built from the input.
void buildFile(Bytes& in, int index, Header& h, gdcm::DataSet& ds) {
    h.path = "fuzz" + std::to_string(index) + ".dcm";
    const int frames = 1 + in.next() % 12;
    const std::uint8_t flags = in.next();
    h.values[kRows] = std::to_string(1 + ((flags & 0x80) ? in.next() % 3 : 1));
    h.values[kColumns] = "2";
    h.values[kNumberOfFrames] = std::to_string((flags & 0x40) ? frames + 1 : frames);
    h.values[kInstanceNumber] = std::to_string(in.next() % 4);
    if (flags & 0x20) h.values[kNumberOfTemporalPositions] = std::to_string(in.next() % 5);
    if (flags & 0x10) h.values[kAcquisitionNumber] = std::to_string(in.next() % 3);
    if (!(flags & 8)) {
        putItem(ds, 0x5200, 0x9229, [&](gdcm::DataSet& shared) {
            putItem(shared, 0x0028, 0x9110, [&](gdcm::DataSet& m) {
                put(m, kPixelSpacing, gdcm::VR::DS, text(in, (flags & 4) ? "1\\1.0002" : "1\\1"));
            });
            putItem(shared, 0x0020, 0x9116, [&](gdcm::DataSet& m) {
                put(m, kImageOrientation, gdcm::VR::DS,
                    text(in, kOrientations[(flags & 2) ? in.next() % 4 : 0]));
            });
        });
    }
    if (flags & 1) return;  // no per-frame groups: a legacy multi-frame file
    gdcm::SmartPointer<gdcm::SequenceOfItems> perFrame = new gdcm::SequenceOfItems;
    const std::uint8_t content = in.next();
    for (int f = 0; f < frames; ++f) {
        gdcm::Item item;
        gdcm::DataSet& g = item.GetNestedDataSet();
        const std::uint8_t own = in.next();
        putItem(g, 0x0020, 0x9113,
                [&](gdcm::DataSet& s) { put(s, kImagePosition, gdcm::VR::DS, positionText(in)); });
        if (own & 1) {
            putItem(g, 0x0020, 0x9116, [&](gdcm::DataSet& s) {
                put(s, kImageOrientation, gdcm::VR::DS, kOrientations[in.next() % 4]);
            });
        }
        if (own & 2) {
            putItem(g, 0x0028, 0x9110, [&](gdcm::DataSet& s) {
                put(s, kPixelSpacing, gdcm::VR::DS, text(in, "1\\1"));
            });
        }
        if (own & 4) {
            putItem(g, 0x0028, 0x9145, [&](gdcm::DataSet& s) {
                put(s, kRescaleSlope, gdcm::VR::DS, text(in, (own & 8) ? "0" : "2.5"));
                put(s, kRescaleIntercept, gdcm::VR::DS, text(in, "-10"));
            });
        }
        putItem(g, 0x0020, 0x9111, [&](gdcm::DataSet& s) { fillFrameContent(in, s, content); });
        perFrame->AddItem(item);
    }
    gdcm::DataElement de(gdcm::Tag(0x5200, 0x9230));
    de.SetVR(gdcm::VR::SQ);
    de.SetValue(*perFrame);
    ds.Replace(de);
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
    Bytes in{data, size};
    const int files = 1 + in.next() % 3;
    std::deque<Header> store;
    std::vector<const Header*> frames;
    try {
        for (int i = 0; i < files; ++i) {
            Header h;
            gdcm::DataSet ds;
            buildFile(in, i, h, ds);
            for (Header& f : frameHeaders(h, ds)) {
                if (f.frame < 1 || f.path != h.path) __builtin_trap();
                store.push_back(std::move(f));
                frames.push_back(&store.back());
            }
        }
        checkFramesAgree(frames);
        const auto positions = framePositions("fuzz", frames);
        const std::size_t timePoints = positions.front().size();
        std::set<const Header*> seen;
        const TimeOrder order(frames, positions);
        const FileGeometry g0 = geometryOf(*frames.front());
        const Eigen::Vector3d normal = g0.rowCosine.cross(g0.columnCosine).normalized();
        double last = -1e300;
        for (const auto& grp : positions) {
            if (grp.size() != timePoints) __builtin_trap();
            const double along = positionOf(*grp.front())->dot(normal);
            if (!(along > last)) __builtin_trap();
            last = along;
            for (std::size_t i = 0; i < grp.size(); ++i) {
                if (!seen.insert(grp[i]).second) __builtin_trap();
                if (i > 0 && order.key(*grp[i]) < order.key(*grp[i - 1])) __builtin_trap();
            }
        }
        if (seen.size() != frames.size()) __builtin_trap();
        palp::volume::ReadOptions options;
        options.timePoint = in.next() % 6;
        const int t = palp::volume::detail::chooseTimePoint(static_cast<std::int64_t>(timePoints),
                                                            options, "fuzz");
        if (t >= static_cast<int>(timePoints)) __builtin_trap();
    } catch (const palp::Error&) {
    }
    return 0;
}
