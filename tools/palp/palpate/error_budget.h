#pragma once
/// @file
/// `palp palpate --error-budget PERCENT|off` (docs/error_analysis.md, "Lookup table and
/// control"): on a deformable body solved by the regions, the primary size and secondary rate
/// are chosen at set-up from palp's error table (haptics::ErrorTable::builtIn()) for the
/// body's material and the worst input the table covers, and the run's contact displacement
/// gives the input's strain and frequency and the error estimated for them; both go into the
/// report.

#include <CLI/CLI.hpp>
#include <Eigen/Core>
#include <memory>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "../palpate_options.h"
#include "palp/haptics/session.h"
#include "palp/haptics/tissue/deformable.h"
#include "palp/haptics/tissue/error_control.h"

namespace palp::tool {

/// The check of --error-budget: "off" or a percentage in (0, 100].
CLI::Validator errorBudgetCheck();
/// --error-budget's percentage; NaN for "off". @throw palp::ValueError naming the option.
double errorBudgetPercent(const std::string& text);

/// The table --error-table names (a file `palp errormap --table` wrote), or palp's built-in
/// one when it is empty. @throw palp::Error naming --error-table and the file's field; a table
/// of the plain coupling is refused (the regions run the condensed one).
std::shared_ptr<const haptics::ErrorTable> errorTableOf(const PalpateArgs& a);

/// The controller's choice for @p model (on the regions) at @p budgetPercent: its lod, the
/// primary's cost around regionsCentreNode() at its tick, the worst input, secondary rates from
/// @p minRateHz (--secondary-hz) up.
haptics::ErrorControlChoice chooseForBody(const haptics::ErrorTable& table,
                                          const haptics::DeformableModel& model,
                                          double budgetPercent, double minRateHz);

/// @p model with the primary size and secondary rate chooseForBody() picks, when the body is
/// on the regions and --error-budget is not off; @p model itself otherwise. Set-up only (before
/// embedded meshes are added: DeformableModel::withOptions()).
std::shared_ptr<haptics::DeformableModel> applyErrorBudget(
    const PalpateArgs& a, std::shared_ptr<haptics::DeformableModel> model);

/// What the report says of the error budget.
struct ErrorBudgetReport {
    bool applies = false;  ///< --error-budget not off and the body on the regions
    double budgetPercent = 0;
    int askedPrimary = 0;  ///< --primary-nodes
    double askedRate = 0;  ///< --secondary-hz
    haptics::ErrorControlChoice choice;
    double referenceLengthMm = 0;  ///< the body's extent along the press (strain = depth / it)
    int windows = 0, windowsOver = 0;
    double maxPercent = 0;   ///< the run's largest estimate (NaN: no window with contact)
    double lastPercent = 0;  ///< the last window's
    double strain = 0, frequencyHz = 0;  ///< the last window's input
    bool lastInRange = false;  ///< the last window's input inside the sweep's ranges (not clamped)
    std::string note;          ///< why it does not apply
    std::string table;         ///< --error-table's file, or "built-in"
};

/// The report of a run on @p model (null: no deformable body): the set-up choice again
/// (deterministic) and the estimate over @p snaps, windows of 0.25 s (the sweep's duration) of
/// the largest surface displacement while in contact.
ErrorBudgetReport errorBudgetReport(const PalpateArgs& a, const haptics::DeformableModel* model,
                                    const std::vector<haptics::Snapshot>& snaps,
                                    const Eigen::Vector3d& press, double periodSeconds);

nlohmann::json errorBudgetJson(const ErrorBudgetReport& r);
void printErrorBudget(const ErrorBudgetReport& r);

}  // namespace palp::tool
