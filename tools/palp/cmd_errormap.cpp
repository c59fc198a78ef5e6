// palp errormap: partial rank correlations of a sweep table's variables with its force error,
// with p-values and confidence intervals, and the error map's figures; with --table, the error
// lookup table fitted to it (docs/error_analysis.md).
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <memory>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "commands.h"
#include "palp/base/atomic_file.h"
#include "palp/base/error.h"
#include "palp/studies/error_table_fit.h"
#include "palp/studies/prcc.h"
#include "palp/studies/sweep_plots.h"

namespace palp::tool {

namespace fs = std::filesystem;
using namespace palp::haptics;

namespace {

struct ErrormapArgs {
    std::string table;
    std::string out;
    std::string response = "err_rms";
    double level = 0.95;
    int maxLines = 2000;
    bool noPlots = false;
    std::vector<std::string> where;
    std::string tableOut;                    ///< --table: the fitted error lookup table (JSON)
    double quantile = 0.95;                  ///< --quantile
    std::string tableResponse = "err_peak";  ///< --table-response
};

/// Keeps the rows of @p t where every "COLUMN=VALUE" of @p where holds (e.g. coupling=0).
SweepTable filtered(const SweepTable& t, const std::vector<std::string>& where) {
    if (where.empty()) return t;
    std::vector<std::pair<int, double>> conds;
    for (const auto& w : where) {
        const auto eq = w.find('=');
        const int c = eq == std::string::npos ? -1 : t.column(w.substr(0, eq));
        char* end = nullptr;
        const double v = c < 0 ? 0.0 : std::strtod(w.c_str() + eq + 1, &end);
        if (c < 0 || end == w.c_str() + eq + 1 || *end != '\0')
            throw ValueError("--where: expected COLUMN=NUMBER with a column of the table, found '" +
                             w + "'");
        conds.emplace_back(c, v);
    }
    std::vector<Eigen::Index> keep;
    for (Eigen::Index r = 0; r < t.data.rows(); ++r) {
        bool ok = true;
        for (const auto& [c, v] : conds) ok = ok && t.data(r, c) == v;
        if (ok) keep.push_back(r);
    }
    SweepTable out = t;
    out.data.resize(static_cast<Eigen::Index>(keep.size()), t.data.cols());
    for (std::size_t i = 0; i < keep.size(); ++i)
        out.data.row(static_cast<Eigen::Index>(i)) = t.data.row(keep[i]);
    return out;
}

void writeText(const fs::path& p, const std::string& what, const std::string& text) {
    writeFileAtomically(p, what, text.data(), text.size());
}

/// The sweep's sidecar (TABLE.json) as read, or an empty object without one.
nlohmann::json sidecar(const std::string& table) {
    fs::path p(table);
    p.replace_extension(".json");
    std::ifstream in(p);
    if (!in) return nlohmann::json::object();
    try {
        return nlohmann::json::parse(in);
    } catch (const nlohmann::json::parse_error& e) {
        throw FormatError(p.string() + ": expected the sweep table's JSON sidecar, found " +
                          e.what());
    }
}

/// --table: fits the lookup table and writes it.
void writeTable(const ErrormapArgs& a, const SweepTable& t) {
    ErrorTableFitOptions o;
    o.response = a.tableResponse;
    o.quantile = a.quantile;
    const nlohmann::json side = sidecar(a.table);
    nlohmann::json prov;
    for (const char* k : {"palp_version", "sweep", "design", "seed", "samples", "parameters"})
        if (side.contains(k)) prov["sweep"][k] = side[k];
    prov["table"] = fs::path(a.table).filename().string();
    prov["where"] = a.where;
    // The axes span the ranges file's [min, max] (the samples' extremes lie inside them).
    const nlohmann::json vars = side.contains("parameters")
                                    ? side["parameters"].value("variables", nlohmann::json())
                                    : nlohmann::json();
    o.axes = defaultErrorAxes(t, [&](ErrorVar v, double& lo, double& hi) {
        const char* n = errorVarName(v);
        if (!vars.is_object() || !vars.contains(n) || !vars[n].contains("min")) return false;
        lo = vars[n]["min"].get<double>();
        hi = vars[n]["max"].get<double>();
        return true;
    });
    ErrorTableFitReport rep;
    // The fit's provenance is completed after it (rows used, coverage).
    ErrorTable table = fitErrorTable(t, o, prov.dump(), &rep);
    prov["fit"] = {{"method",
                    "per lod: log(max(error, floor)) as a sum of piecewise-linear functions "
                    "of the other axes (penalised least squares), plus the quantile of the "
                    "residuals"},
                   {"floor_percent", o.floorPercent},
                   {"smoothing", o.smoothing},
                   {"rows_used", rep.rowsUsed},
                   {"rows_non_finite", rep.rowsNonFinite},
                   {"coverage", rep.coverage},
                   {"median_estimate_over_error", rep.medianRatio}};
    table.provenance = prov.dump();
    const std::string text = table.toJson();
    writeFileAtomically(a.tableOut, "error table", text.data(), text.size());
    std::printf(
        "error table %s: %s, %.0f %% quantile, %zu axes, %zu nodes, %d rows (%d non-finite "
        "left out); %.1f %% of the rows at or below their estimate, median estimate / error "
        "%.2f\n",
        a.tableOut.c_str(), a.tableResponse.c_str(), 100 * a.quantile, table.axes().size(),
        table.errorPercent().size(), rep.rowsUsed, rep.rowsNonFinite, 100 * rep.coverage,
        rep.medianRatio);
}

int run(const ErrormapArgs& a) {
    const SweepTable t = filtered(readSweepTable(a.table), a.where);
    if (!a.tableOut.empty()) writeTable(a, t);
    if (a.out.empty()) return 0;
    int dropped = 0, used = 0;
    const auto prcc = sweepPrcc(t, a.response, a.level, &dropped, &used);
    const fs::path dir(a.out);
    std::error_code ec;
    fs::create_directories(dir, ec);
    if (ec) throw IoError(dir.string() + ": cannot create the output directory: " + ec.message());
    const int k = static_cast<int>(prcc.size()) - 1;
    const int dof = used - 2 - k;
    std::string csv = "variable,unit,prcc,t,dof,p,ci_low,ci_high\n";
    nlohmann::json j;
    j["table"] = fs::absolute(a.table).string();
    j["response"] = a.response;
    j["where"] = a.where;
    j["rows_used"] = used;
    j["rows_dropped_nonfinite"] = dropped;
    j["controlled_variables"] = k;
    j["dof"] = dof;
    j["confidence_level"] = a.level;
    j["method"] =
        "PRCC: Pearson correlation of the residuals of rank(x_j) and rank(y) after "
        "least squares on the other variables' ranks (average ranks for ties); "
        "t = r sqrt(dof / (1 - r^2)), dof = n - 2 - k, two-sided p; interval "
        "tanh(atanh r -+ z_(1+level)/2 / sqrt(n - 3 - k))";
    std::printf(
        "PRCC with %s over %d samples (%d dropped: non-finite), k = %d controlled, "
        "dof = %d, %.0f %% intervals\n",
        a.response.c_str(), used, dropped, k, dof, 100 * a.level);
    std::printf("%-12s %-7s %9s %10s %11s %21s\n", "variable", "unit", "PRCC", "t", "p",
                "interval");
    char buf[256];
    for (const auto& e : prcc) {
        std::snprintf(buf, sizeof buf, "%s,%s,%.17g,%.17g,%d,%.17g,%.17g,%.17g\n", e.name.c_str(),
                      e.unit.c_str(), e.r, e.t, dof, e.p, e.lower, e.upper);
        csv += buf;
        j["variables"].push_back({{"name", e.name},
                                  {"unit", e.unit},
                                  {"prcc", e.r},
                                  {"t", e.t},
                                  {"p", e.p},
                                  {"ci", {e.lower, e.upper}}});
        std::printf("%-12s %-7s %+9.4f %10.3f %11.3g   [%+.4f, %+.4f]\n", e.name.c_str(),
                    e.unit.c_str(), e.r, e.t, e.p, e.lower, e.upper);
    }
    writeText(dir / "prcc.csv", "PRCC table", csv);
    writeText(dir / "prcc.json", "PRCC summary", j.dump(2) + "\n");
    if (!a.noPlots) writeSweepPlots(t, a.response, prcc, dir, a.maxLines);
    return 0;
}

}  // namespace

Command addErrormap(CLI::App& root) {
    auto args = std::make_shared<ErrormapArgs>();
    CLI::App* app =
        root.add_subcommand("errormap",
                            "Partial rank correlations of a sweep table with its error, and the "
                            "error map's plots (PNG, SVG, PDF)");
    app->add_option("table", args->table, "Sweep table (CSV with its .json sidecar)")->required();
    app->add_option("-o,--out", args->out, "Output directory (PRCC and plots)");
    app->add_option("--response", args->response, "Error column: err_rms, err_peak or err_max")
        ->capture_default_str();
    app->add_option("--level", args->level, "Confidence level of the intervals")
        ->check(CLI::Range(0.5, 0.9999))
        ->capture_default_str();
    app->add_option("--max-lines", args->maxLines, "Samples drawn in the parallel coordinates")
        ->check(CLI::Range(1, 1000000))
        ->capture_default_str();
    app->add_flag("--no-plots", args->noPlots, "Only the tables");
    app->add_option("--where", args->where,
                    "Analyse only the rows where COLUMN=VALUE (repeatable; e.g. coupling=0)");
    app->add_option("--table", args->tableOut,
                    "Fit the error lookup table to the (filtered) rows and write it here (JSON; "
                    "palp palpate --error-budget reads such a table)");
    app->add_option("--quantile", args->quantile,
                    "--table: the quantile of the error the table's nodes hold")
        ->check(CLI::Range(0.5, 0.999))
        ->capture_default_str();
    app->add_option("--table-response", args->tableResponse,
                    "--table: the error column fitted (err_peak, err_rms or err_max)")
        ->check(CLI::IsMember({"err_peak", "err_rms", "err_max"}))
        ->capture_default_str();
    return {app, [args]() -> int {
                if (args->out.empty() && args->tableOut.empty())
                    throw ValueError("errormap: expected -o DIR, --table FILE or both");
                return run(*args);
            }};
}

}  // namespace palp::tool
