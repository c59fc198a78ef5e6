#include "error_budget.h"

#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <limits>

#include "palp/base/error.h"

namespace palp::tool {

// Named, not anonymous: the tool's sources are compiled in unity batches.
namespace error_budget_impl {

constexpr double kWindowSeconds = 0.25;  // the sweep's duration: one estimate per window

std::string expectedBudget() {
    return "expected 'off' or a percentage in (0, 100] (default 5.23, the stiffness JND for "
           "normal pressure)";
}

/// The percentage in @p text, NaN for "off"; an empty string when it is neither.
bool parseBudget(const std::string& text, double& out) {
    if (text == "off") {
        out = std::numeric_limits<double>::quiet_NaN();
        return true;
    }
    const char* begin = text.c_str();
    char* end = nullptr;
    out = std::strtod(begin, &end);
    return !text.empty() && end != begin && *end == '\0' && std::isfinite(out) && out > 0 &&
           out <= 100;
}

bool onRegions(const haptics::DeformableModel& m) {
    return m.options().solverKind == haptics::DeformableSolver::asyncRegions;
}

}  // namespace error_budget_impl

using namespace error_budget_impl;

CLI::Validator errorBudgetCheck() {
    return CLI::Validator(
        [](std::string& text) -> std::string {
            double v = 0;
            if (parseBudget(text, v)) return {};
            return expectedBudget() + ", found " +
                   (text.empty() ? std::string("an empty value") : "'" + text + "'");
        },
        "'off' or PERCENT in (0, 100]");
}

double errorBudgetPercent(const std::string& text) {
    double v = 0;
    if (!parseBudget(text, v))
        throw ValueError("--error-budget: " + expectedBudget() + ", found '" + text + "'");
    return v;
}

std::shared_ptr<const haptics::ErrorTable> errorTableOf(const PalpateArgs& a) {
    if (a.errorTable.empty())
        return std::shared_ptr<const haptics::ErrorTable>(&haptics::ErrorTable::builtIn(),
                                                          [](const haptics::ErrorTable*) {});
    try {
        auto t =
            std::make_shared<const haptics::ErrorTable>(haptics::ErrorTable::load(a.errorTable));
        if (t->coupling != 1)
            throw ValueError(a.errorTable +
                             ": coupling: expected 1 (the condensed coupling the regions run), "
                             "found " +
                             std::to_string(t->coupling));
        return t;
    } catch (const IoError& e) {
        throw IoError(std::string("--error-table: ") + e.what());
    } catch (const FormatError& e) {
        throw FormatError(std::string("--error-table: ") + e.what());
    } catch (const ValueError& e) {
        throw ValueError(std::string("--error-table: ") + e.what());
    }
}

haptics::ErrorControlChoice chooseForBody(const haptics::ErrorTable& table,
                                          const haptics::DeformableModel& model,
                                          double budgetPercent, double minRateHz) {
    const fem::AsyncRegionsOptions& r = model.options().regions;
    const int centre = model.regionsCentreNode();
    haptics::ErrorControlOptions o;
    o.budgetPercent = budgetPercent;
    // The rate may rise above the one asked for, never fall below it: the sweep drives the
    // contact inside the primary, so it does not see how late a slower secondary passes on
    // the loads that fall outside it (the filter's tail, a contact between two layouts).
    std::vector<double> rates{minRateHz};
    for (double f : o.rateCandidates)
        if (f > minRateHz) rates.push_back(f);
    o.rateCandidates = rates;
    const auto cost = [&](int n) {
        return haptics::primaryCost(model.model(), centre, r.lod, n, r.safetyFactor, r.tickSeconds);
    };
    return haptics::chooseRegionsSetting(table, haptics::errorConditions(model), r.lod, cost, o);
}

std::shared_ptr<haptics::DeformableModel> applyErrorBudget(
    const PalpateArgs& a, std::shared_ptr<haptics::DeformableModel> model) {
    const double budget = errorBudgetPercent(a.errorBudget);
    if (std::isnan(budget) || !onRegions(*model)) return model;
    const haptics::ErrorControlChoice c =
        chooseForBody(*errorTableOf(a), *model, budget, a.secondaryHz);
    haptics::DeformableOptions o = model->options();
    if (o.regions.primaryNodes == c.setting.primaryNodes &&
        o.regions.secondaryRate == c.setting.secondaryRate)
        return model;
    o.regions.primaryNodes = c.setting.primaryNodes;
    o.regions.secondaryRate = c.setting.secondaryRate;
    return model->withOptions(o);
}

ErrorBudgetReport errorBudgetReport(const PalpateArgs& a, const haptics::DeformableModel* model,
                                    const std::vector<haptics::Snapshot>& snaps,
                                    const Eigen::Vector3d& press, double periodSeconds) {
    ErrorBudgetReport r;
    r.askedPrimary = a.primaryNodes;
    r.askedRate = a.secondaryHz;
    const double budget = errorBudgetPercent(a.errorBudget);
    r.budgetPercent = budget;
    if (std::isnan(budget)) {
        r.note = "--error-budget off: the regions' options as given";
        return r;
    }
    if (!model || !onRegions(*model)) {
        r.note = model ? "the whole mesh: no regions to control" : "no deformable body";
        return r;
    }
    r.applies = true;
    // The body was built with the choice (applyErrorBudget); choosing again gives it back.
    const auto table = errorTableOf(a);
    r.table = a.errorTable.empty() ? "built-in" : a.errorTable;
    r.choice = chooseForBody(*table, *model, budget, a.secondaryHz);
    const fem::HexMesh& mesh = model->model().mesh();
    Eigen::Index axis = 0;
    press.cwiseAbs().maxCoeff(&axis);
    const double length = (mesh.nodeCounts()[static_cast<std::size_t>(axis)] - 1) * mesh.edge();
    r.referenceLengthMm = length * 1e3;
    haptics::ErrorMonitor m(*table, haptics::errorConditions(*model), length, kWindowSeconds,
                            periodSeconds, budget);
    for (const haptics::Snapshot& s : snaps)
        m.update(s.contactCount > 0 ? s.maxDisplacement : std::numeric_limits<double>::quiet_NaN());
    r.windows = m.windows();
    r.windowsOver = m.windowsOverBudget();
    r.maxPercent = m.maxPercent();
    r.lastPercent = m.current().percent;
    r.strain = m.strain();
    r.frequencyHz = m.frequency();
    r.lastInRange = m.current().inRange();
    return r;
}

nlohmann::json errorBudgetJson(const ErrorBudgetReport& r) {
    nlohmann::json j;
    j["applies"] = r.applies;
    if (!r.applies) {
        j["note"] = r.note;
        if (!std::isnan(r.budgetPercent)) j["budget_percent"] = r.budgetPercent;
        return j;
    }
    const haptics::ErrorControlChoice& c = r.choice;
    auto num = [](double v) { return std::isfinite(v) ? nlohmann::json(v) : nlohmann::json(); };
    j["budget_percent"] = r.budgetPercent;
    j["table"] = r.table;
    j["asked"] = {{"primary_nodes", r.askedPrimary}, {"secondary_hz", r.askedRate}};
    j["chosen"] = {{"primary_nodes", c.setting.primaryNodes},
                   {"secondary_hz", c.setting.secondaryRate},
                   {"lod", c.setting.lod}};
    j["predicted_percent_worst_input"] = num(c.predicted.percent);
    j["predicted_in_sweep_ranges"] = c.predicted.inRange();
    j["meets_budget"] = c.meetsBudget;
    j["primary_cells"] = c.cost.cells;
    j["element_substeps"] = c.cost.elementSubsteps();
    j["meets_tick"] = c.meetsTime;
    j["reason"] = c.reason;
    j["run"] = {{"windows", r.windows},
                {"windows_over_budget", r.windowsOver},
                {"max_percent", num(r.maxPercent)},
                {"last_percent", num(r.lastPercent)},
                {"last_strain", num(r.strain)},
                {"last_frequency_hz", num(r.frequencyHz)},
                {"last_in_sweep_ranges", r.lastInRange},
                {"reference_length_mm", r.referenceLengthMm}};
    return j;
}

void printErrorBudget(const ErrorBudgetReport& r) {
    if (!r.applies) {
        if (!std::isnan(r.budgetPercent) && r.note != "no deformable body")
            std::printf("error budget: %s\n", r.note.c_str());
        return;
    }
    std::printf("error budget %.2f %%: %s (asked: %d seeds, %g Hz)\n", r.budgetPercent,
                r.choice.reason.c_str(), r.askedPrimary, r.askedRate);
    if (r.windows > 0)
        std::printf(
            "error estimate over the run: max %.2f %%, last %.2f %% (strain %.3f, %.1f Hz%s); "
            "%d of %d windows of 0.25 s over the budget\n",
            r.maxPercent, r.lastPercent, r.strain, r.frequencyHz,
            r.lastInRange ? "" : ", outside the sweep's ranges: clamped", r.windowsOver, r.windows);
    else
        std::printf("error estimate over the run: no window with contact\n");
}

}  // namespace palp::tool
