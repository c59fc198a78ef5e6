#pragma once
/// @file
/// The error map's figures (docs/error_analysis.md), drawn with cairo as PNG, SVG and PDF:
/// a parallel-coordinates plot of the analysed variables and the error, and one panel per
/// variable with the error against it (a scatter for continuous variables, box plots for those
/// with at most 8 values), each panel titled with its PRCC.

#include <filesystem>
#include <string>
#include <vector>

#include "palp/studies/prcc.h"

namespace palp::haptics {

/// Writes `parallel.{png,svg,pdf}` and `variables.{png,svg,pdf}` into @p dir (which must exist)
/// for the variables of @p prcc against the column @p response of @p table (rows with a
/// non-finite response left out). At most @p maxLines rows are drawn in the parallel
/// coordinates (every k-th row, deterministic). Each file is written atomically.
/// @throw palp::IoError when cairo cannot write a file; palp::ValueError for an unknown column.
void writeSweepPlots(const SweepTable& table, const std::string& response,
                     const std::vector<PrccEntry>& prcc, const std::filesystem::path& dir,
                     int maxLines = 2000);

}  // namespace palp::haptics
