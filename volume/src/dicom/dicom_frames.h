#pragma once
// Enhanced (functional group) multi-frame DICOM (internal): every frame of a file as its own
// Header, from the file's values, the Shared Functional Groups Sequence (5200,9229) and the
// frame's item of the Per-frame Functional Groups Sequence (5200,9230); the checks that the
// frames of a series split over several files (Siemens XA: one file per time point, or the
// slices of a volume over several files) form one grid of positions x time points.
#include <gdcmDataSet.h>

#include <deque>
#include <string>
#include <vector>

#include "dicom/dicom_header.h"
#include "dicom/dicom_slices.h"

namespace palp::volume::dicom {

/// Number Of Frames (0028,0008) of @p h; 1 when absent.
int frameCountOf(const Header& h);

/// The frames of the enhanced multi-frame file @p h (its data set @p ds, pixel data not needed):
/// each Header carries the file's values overridden by the shared functional groups, then by
/// the frame's own: Pixel Measures (spacing, thickness), Plane Position, Plane Orientation,
/// Pixel Value Transformation (rescale) and Frame Content (Temporal Position Index, Dimension
/// Index Values, Frame Acquisition DateTime).
/// @throw FormatError naming the file when the per-frame groups are missing (a legacy
///        multi-frame image) or do not hold one item per frame.
std::vector<Header> frameHeaders(const Header& h, const gdcm::DataSet& ds);

/// Reads @p h's data set up to its pixel data and returns frameHeaders().
/// @throw FormatError naming the file (unreadable, or see frameHeaders).
std::vector<Header> readFrameHeaders(const Header& h);

/// The images of a series as frames: single-frame files as they are, enhanced multi-frame
/// files replaced by their frames (held in @p store).
/// @throw FormatError (see readFrameHeaders).
std::vector<const Header*> expandFrames(const std::vector<const Header*>& images,
                                        std::deque<Header>& store);

/// Whether any of @p images is a multi-frame file.
bool hasMultiFrame(const std::vector<const Header*>& images);

/// Checks that every frame of @p frames has the size (Rows, Columns), orientation and pixel
/// spacing of the first (orientation to 1e-4, spacing to 1e-4 relative).
/// @throw FormatError naming the frame (file and frame number), what the first frame has and
///        what it has.
void checkFramesAgree(const std::vector<const Header*>& frames);

/// The frames of a series grouped by position (increasing along the first frame's normal), each
/// group in time order (TimeOrder), checked: no two frames at one position that time cannot tell
/// apart (duplicates), the same number of frames at every position, and Temporal Position Index
/// values (where every frame has one) that run without a gap and agree with Number of Temporal
/// Positions (0020,0105) where the files give it.
/// @throw FormatError (geometry, duplicates, gaps), ValueError (counts) naming @p name and the
///        frames.
std::vector<std::vector<const Header*>> framePositions(const std::string& name,
                                                       const std::vector<const Header*>& frames);

}  // namespace palp::volume::dicom
