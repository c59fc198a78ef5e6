#pragma once
// Slice ordering and geometry of a DICOM series (internal): grouping images by position along
// the slice normal, ordering the images of one position in time, the memory check, and the
// geometry and VolumeInfo of the slices read.
#include <cstddef>
#include <cstdint>
#include <filesystem>
#include <string>
#include <vector>

#include "dicom_header.h"
#include "palp/volume/slice_stack.h"

namespace palp::volume::dicom {

/// Tolerance (mm) below which two slice positions along the normal count as the same.
double positionTolerance(const Header& h);

/// Groups images by position along the normal @p n; groups in increasing position.
/// Images without a position each form their own group.
std::vector<std::vector<const Header*>> groupPositions(const std::vector<const Header*>& images,
                                                       const Eigen::Vector3d& n, double tolMm);

/// Groups @p images by position and checks that every position holds the same number.
/// @throw ValueError naming @p name when the counts differ.
std::vector<std::vector<const Header*>> positionGroups(const std::string& name,
                                                       const std::vector<const Header*>& images,
                                                       const FileGeometry& first);

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

/// Refuses @p slices slices of @p cols x @p rows floats when they exceed @p limit bytes.
/// @throw ValueError naming @p name.
void checkMemory(const std::string& name, int cols, int rows, std::size_t slices,
                 std::uint64_t limit);

/// Sets @p s's position and steps (metres) from the file geometry @p g (mm).
void setGeometry(const FileGeometry& g, Slice& s);

/// Fills @p info from the first file of the series and what was read.
void fillInfo(VolumeInfo& info, const Header& first,
              const std::vector<std::filesystem::path>& inputs, const std::string& uid,
              std::size_t positions, int timePoint, int timePointCount, bool rescaleVaries);

}  // namespace palp::volume::dicom
