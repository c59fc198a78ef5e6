#pragma once
/// @file
/// Partial rank correlation coefficients (PRCC, Spearman partial correlation) of a sweep's
/// variables with its error (docs/error_analysis.md), with t-test p-values and Fisher-z
/// confidence intervals; and reading a sweep table back.

#include <Eigen/Core>
#include <filesystem>
#include <string>
#include <vector>

namespace palp::haptics {

/// Average ranks (1-based; ties share the mean of their positions) of @p v.
Eigen::VectorXd averageRanks(const Eigen::VectorXd& v);

/// One variable's partial rank correlation with the response.
struct PrccEntry {
    std::string name;
    std::string unit;
    double r = 0.0;      ///< PRCC in [-1, 1]
    double t = 0.0;      ///< r sqrt(dof / (1 - r^2))
    double p = 0.0;      ///< two-sided p-value of t with dof = n - 2 - k degrees of freedom
    double lower = 0.0;  ///< confidence interval of r: tanh(atanh r -+ z / sqrt(n - 3 - k))
    double upper = 0.0;
};

/// PRCC of every column of @p x (n x m, m >= 1) with @p y (n): the correlation of the residuals
/// of rank(x_j) and rank(y) after a least-squares fit (with intercept) on the ranks of the other
/// m - 1 = k columns. @p level is the confidence level of the intervals (e.g. 0.95).
/// @throw palp::ValueError when n <= m + 3 (no degrees of freedom left), a column is constant,
/// or the sizes disagree.
std::vector<PrccEntry> partialRankCorrelation(const Eigen::MatrixXd& x, const Eigen::VectorXd& y,
                                              const std::vector<std::string>& names,
                                              double level = 0.95);

/// A sweep table read back (CSV with the JSON sidecar beside it, same stem).
struct SweepTable {
    std::vector<std::string> names, units, roles, descriptions;  ///< per column
    Eigen::MatrixXd data;                                        ///< rows x columns
    /// Index of column @p name, -1 if absent.
    int column(const std::string& name) const;
};
/// Reads @p csv and its sidecar (@p csv with extension ".json"; without a sidecar every column
/// is a "variable" of unit "1"). Cells "inf"/"nan" read as such.
/// @throw palp::IoError, palp::FormatError naming the file, line and column.
SweepTable readSweepTable(const std::filesystem::path& csv);

/// What `palp errormap` analyses: the varying "variable" and "derived" columns (the contact
/// node and primary free node count excluded: they restate the contact rank and primary size)
/// against @p response, over the rows whose response is finite. Fills @p dropped with the rows
/// left out. @throw palp::ValueError naming the response when it is not a column.
std::vector<PrccEntry> sweepPrcc(const SweepTable& table, const std::string& response, double level,
                                 int* dropped, int* used);

}  // namespace palp::haptics
