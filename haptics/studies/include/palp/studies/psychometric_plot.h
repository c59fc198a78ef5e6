#pragma once
/// @file
/// The psychometric plot of a study (cairo: PNG, SVG and PDF): one panel per condition with the
/// proportion correct at each level (discs of area proportional to the trials there), the
/// fitted psychometric function, its bootstrap band (pointwise percentile interval of the
/// refits' curves, at the fit's coverage), the threshold at the procedure's target marked with
/// its interval and the staircase's threshold from reversals, axes in percent increment of the
/// reference stiffness and in proportion correct.

#include <filesystem>
#include <string>
#include <vector>

#include "palp/studies/study_runner.h"

namespace palp::haptics {

/// Writes @p stem .png, .svg and .pdf (each atomically; an existing file is replaced only by a
/// complete one). @p coverage labels the band.
/// @throw palp::IoError naming the file cairo cannot write; palp::ValueError for no results.
void writePsychometricPlot(const std::filesystem::path& stem,
                           const std::vector<ConditionResult>& results, const std::string& title,
                           double coverage = 0.95);

}  // namespace palp::haptics
