#pragma once
// Slice ordering and geometry of a DICOM series (internal): grouping images by position along
// the slice normal, ordering the images of one position in time, the memory check, and the
// geometry and VolumeInfo of the slices read.
#include <cstddef>
#include <cstdint>
#include <filesystem>
#include <string>
#include <vector>

#include "dicom/dicom_header.h"
#include "palp/volume/slice_stack.h"

namespace palp::volume::dicom {

/// Tolerance (mm) below which two slice positions along the normal count as the same.
double positionTolerance(const Header& h);

/// Groups images by position along the normal @p n; groups in increasing position.
/// Images without a position each form their own group.
std::vector<std::vector<const Header*>> groupPositions(const std::vector<const Header*>& images,
                                                       const Eigen::Vector3d& n, double tolMm);

/// Checks that every group of @p positions (along @p normal) holds as many images as the first.
/// @throw ValueError naming @p name, the position and an image there when the counts differ.
void checkSameCount(const std::string& name,
                    const std::vector<std::vector<const Header*>>& positions,
                    const Eigen::Vector3d& normal);

/// Orders the images of one position in time. Frames of enhanced files first by their own
/// Temporal Position Index (0020,9128), Frame Acquisition DateTime (0018,9074) and Dimension
/// Index Values (0020,9157); then, for every image, TemporalPositionIdentifier (0020,0100); then
/// InstanceNumber (0020,0013) where no two images of one position share one (as dcm2niix orders
/// classic files: the scanner numbers images in acquisition order); only where instance numbers
/// repeat at a position (they restart with each acquisition) AcquisitionNumber, AcquisitionTime
/// (or ContentTime), InstanceNumber. Then file name and frame. AcquisitionNumber is not trusted
/// before the instance number because it need not be constant over a volume: a Philips classic
/// DTI series numbers the images of one b = 0 volume 19 and 22, and ordering by it put 10 of 82
/// positions' b = 1000 images into volume 0. A key is used only when every image of the series
/// has it, so the comparison stays a strict weak order; a frame-level key only when its value
/// varies over the series. checkDiffusionPerTimePoint() refuses what the order cannot fix.
struct TimeOrder {
    bool useTemporalIndex = true, useFrameTime = true, useDimensionIndex = true;
    bool useTemporal = true, useAcqNumber = true, useAcqTime = true, useContentTime = true,
         useInstance = true;
    /// Instance numbers are unique at every position: they alone order it after the keys above.
    bool instanceDecides = false;
    std::size_t dimensionCount = 0;

    /// The order of @p images, grouped by position in @p positions (groupPositions()).
    TimeOrder(const std::vector<const Header*>& images,
              const std::vector<std::vector<const Header*>>& positions);

    /// The time key of @p h (the keys in use, in order).
    std::vector<double> key(const Header& h) const;

    /// Whether a frame-level key (Temporal Position Index, Frame Acquisition DateTime, Dimension
    /// Index Values) is in use: then two frames of one file with equal keys are duplicates.
    bool frameKeys() const { return useTemporalIndex || useFrameTime || useDimensionIndex; }

    /// The keys in use of @p h, named, for messages ("Temporal Position Index 2, ...").
    std::string describe(const Header& h) const;

    /// Sorts @p images (of one position) in time; ties by file name, then frame.
    void sort(std::vector<const Header*>& images) const;
};

/// Checks that each time point of @p positions (each group in time order) holds one diffusion
/// weighting: where every image has Diffusion b-value (0018,9087), all the images of a time point
/// must have the same b-value (1e-3 s/mm^2), and where every image also has Diffusion Gradient
/// Orientation (0018,9089), the same orientation (1e-4). A volume that mixes them would be a
/// silently wrong image.
/// @throw ValueError naming @p name, the time point, the two images and their values.
void checkDiffusionPerTimePoint(const std::string& name,
                                const std::vector<std::vector<const Header*>>& positions,
                                const TimeOrder& order);

/// Checks that time point @p t of a series whose positions hold different numbers of images
/// (@p positions, each in time order; a 4D acquisition stopped early or missing files) is
/// nevertheless whole: every position holds an image at rank @p t, and when each image was
/// acquired (its acquisition, else content, time, then its instance number, as far as every
/// image has them) tells the time points apart around it: the rank t - 1 images all precede the
/// rank t images, which all precede the rank t + 1 images. A position that lost an earlier image
/// would put a later time point's image at rank t, acquired after a rank t + 1 image of another
/// position.
/// @throw ValueError naming @p name: a position without rank t, images with neither key, or
///        keys that do not separate the ranks (naming the two images).
void checkPartialTimePoint(const std::string& name,
                           const std::vector<std::vector<const Header*>>& positions, std::size_t t);

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
