// palp errormap: partial rank correlations of a sweep table's variables with its force error,
// with p-values and confidence intervals, and the error map's figures (docs/error_analysis.md).
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <memory>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "commands.h"
#include "palp/base/atomic_file.h"
#include "palp/base/error.h"
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

int run(const ErrormapArgs& a) {
    const SweepTable t = filtered(readSweepTable(a.table), a.where);
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
    app->add_option("-o,--out", args->out, "Output directory")->required();
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
    return {app, [args]() -> int { return run(*args); }};
}

}  // namespace palp::tool
