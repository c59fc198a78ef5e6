#pragma once
/// @file
/// Fits the regions' error lookup table (palp/haptics/tissue/error_table.h) to a sweep table
/// (`palp errormap TABLE.csv --table OUT.json`; docs/error_analysis.md, "Lookup table and
/// control").
///
/// Method. Axes whose column only takes node values (the level of detail) split the rows; in
/// each split, y = log(max(error, floor)) is fitted by penalised least squares as a sum of one
/// piecewise-linear function per other axis (hat functions on the axis's nodes; the penalty is
/// `smoothing` times the squared changes of each function's slope at its nodes (second
/// differences on even nodes), plus 1e-9
/// times their squares to fix the constant each function could trade with another). The node
/// value is `100 exp(fit + q)` with q the `quantile` of the split's residuals, so about that
/// fraction of the sweep's samples lies below the table (checked by fittedCoverage()). Rows
/// whose response is not finite (a diverged sample) are counted and left out.

#include <functional>
#include <string>
#include <vector>

#include "palp/haptics/tissue/error_table.h"
#include "palp/studies/prcc.h"

namespace palp::haptics {

/// What fitErrorTable() fits and how.
struct ErrorTableFitOptions {
    std::string response = "err_peak";  ///< err_peak, err_rms or err_max
    double quantile = 0.95;             ///< of the residuals, in (0, 1)
    double floorPercent = 0.01;         ///< errors below it count as it (log), percent
    double smoothing = 1.0;             ///< weight of the second differences (per row)
    /// The axes; empty: defaultErrorAxes().
    std::vector<ErrorTable::Axis> axes;
};

/// Default axes for @p table: lod at its distinct values; primary, rate, poisson, youngs (at
/// nodes spread evenly, youngs geometrically), frequency and strain at 3 nodes each over the
/// columns' ranges, or over the ranges @p range gives (true: the variable's [lo, hi] from the
/// sweep's ranges file, so the table spans the nominal ranges rather than the samples' extremes);
/// variables that do not vary in the table are left out.
std::vector<ErrorTable::Axis> defaultErrorAxes(
    const SweepTable& table,
    const std::function<bool(ErrorVar, double& lo, double& hi)>& range = {});

/// What the fit reports besides the table.
struct ErrorTableFitReport {
    int rowsUsed = 0;
    int rowsNonFinite = 0;   ///< left out
    double coverage = 0;     ///< fraction of used rows whose error <= the table's estimate
    double medianRatio = 0;  ///< median of estimate / error over the used rows
};

/// Fits the table (see the file's comment). @p provenance (a JSON object's text) is stored
/// in it. @throw palp::ValueError naming the response or an axis that is not a column of
/// @p table, a split with fewer rows than parameters, bad options.
ErrorTable fitErrorTable(const SweepTable& table, const ErrorTableFitOptions& options,
                         const std::string& provenance, ErrorTableFitReport* report = nullptr);

}  // namespace palp::haptics
