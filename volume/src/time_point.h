#pragma once
// Choosing the time point (volume) of a 4D source: one rule for every reader (not installed).

#include <cstdint>
#include <string>

#include "palp/volume/read_options.h"

namespace palp::volume::detail {

/// Chooses one time point of a source holding @p count of them (one per volume of a 4D file,
/// or per repeated slice position of a DICOM series). A source with one time point needs no
/// choice and accepts 0, its only one; a source with more needs options.timePoint within
/// 0..count-1.
/// @return the chosen 0-based index, or -1 for a source with one time point.
/// @throw ValueError naming @p item, the number of time points and what was asked for, in the
///        library's words ("time point"); tools map that to their own flag.
int chooseTimePoint(std::int64_t count, const ReadOptions& options, const std::string& item);

}  // namespace palp::volume::detail
