// Fits the regions' error lookup table to a sweep table (error_table_fit.h).
#include "palp/studies/error_table_fit.h"

#include <Eigen/Cholesky>
#include <algorithm>
#include <cmath>
#include <map>

#include "palp/base/error.h"

namespace palp::haptics {

namespace error_fit_impl {

using Index = Eigen::Index;

std::size_t sz(Index i) { return static_cast<std::size_t>(i); }

/// Hat-function weights of @p x on @p nodes: the lower node and the upper node's weight
/// (x clamped to the nodes' range).
std::pair<std::size_t, double> hat(const std::vector<double>& nodes, double x) {
    x = std::clamp(x, nodes.front(), nodes.back());
    std::size_t i = 0;
    while (i + 2 < nodes.size() && x >= nodes[i + 1]) ++i;
    return {i, (x - nodes[i]) / (nodes[i + 1] - nodes[i])};
}

double quantileOf(std::vector<double> v, double q) {
    if (v.empty()) return 0;
    std::sort(v.begin(), v.end());
    const double pos = q * static_cast<double>(v.size() - 1);
    const auto lo = static_cast<std::size_t>(std::floor(pos));
    const std::size_t hi = std::min(lo + 1, v.size() - 1);
    return v[lo] + (pos - static_cast<double>(lo)) * (v[hi] - v[lo]);
}

std::vector<double> spread(double lo, double hi, int n, bool geometric) {
    std::vector<double> v(static_cast<std::size_t>(n));
    for (int i = 0; i < n; ++i) {
        const double t = static_cast<double>(i) / (n - 1);
        v[static_cast<std::size_t>(i)] = geometric ? lo * std::pow(hi / lo, t) : lo + t * (hi - lo);
    }
    return v;
}

}  // namespace error_fit_impl

using namespace error_fit_impl;

std::vector<ErrorTable::Axis> defaultErrorAxes(
    const SweepTable& t, const std::function<bool(ErrorVar, double&, double&)>& nominal) {
    std::vector<ErrorTable::Axis> axes;
    auto range = [&](ErrorVar v, double& lo, double& hi) {
        const int c = t.column(errorVarName(v));
        if (c < 0 || t.data.rows() == 0) return false;
        lo = t.data.col(c).minCoeff();
        hi = t.data.col(c).maxCoeff();
        if (!(hi > lo)) return false;
        double a = lo, b = hi;
        if (nominal && nominal(v, a, b) && a <= lo && b >= hi && a < b) {
            lo = a;
            hi = b;
        }
        return true;
    };
    double lo = 0, hi = 0;
    if (range(ErrorVar::lod, lo, hi)) {
        std::vector<double> values;
        for (Index r = 0; r < t.data.rows(); ++r) values.push_back(t.data(r, t.column("lod")));
        std::sort(values.begin(), values.end());
        values.erase(std::unique(values.begin(), values.end()), values.end());
        axes.push_back({ErrorVar::lod, values});
    }
    if (range(ErrorVar::primary, lo, hi)) {
        std::vector<double> v{lo};
        for (double n : {10.0, 15.0, 20.0, 30.0, 40.0})
            if (n > lo + 2 && n < hi - 2) v.push_back(n);
        v.push_back(hi);
        axes.push_back({ErrorVar::primary, v});
    }
    if (range(ErrorVar::rate, lo, hi)) axes.push_back({ErrorVar::rate, spread(lo, hi, 3, true)});
    for (ErrorVar v : {ErrorVar::poisson, ErrorVar::frequency, ErrorVar::strain})
        if (range(v, lo, hi)) axes.push_back({v, spread(lo, hi, 3, false)});
    if (range(ErrorVar::youngs, lo, hi))
        axes.push_back({ErrorVar::youngs, spread(lo, hi, 3, lo > 0)});
    return axes;
}

ErrorTable fitErrorTable(const SweepTable& t, const ErrorTableFitOptions& o,
                         const std::string& provenance, ErrorTableFitReport* report) {
    if (!(o.quantile > 0 && o.quantile < 1))
        throw ValueError("error table fit: quantile: expected a value in (0, 1), found " +
                         std::to_string(o.quantile));
    if (!(o.floorPercent > 0) || !(o.smoothing >= 0))
        throw ValueError("error table fit: expected floorPercent > 0 and smoothing >= 0");
    const int yc = t.column(o.response);
    if (yc < 0)
        throw ValueError("error table fit: response '" + o.response +
                         "': expected a column of the sweep table, found none");
    std::vector<ErrorTable::Axis> axes = o.axes.empty() ? defaultErrorAxes(t) : o.axes;
    ErrorTable shape(axes,
                     std::vector<double>(
                         [&] {
                             std::size_t n = 1;
                             for (const auto& a : axes) n *= a.values.size();
                             return n;
                         }(),
                         0.0),
                     "error table fit");  // checks the axes
    const std::size_t nAxes = axes.size();
    std::vector<int> col(nAxes);
    std::vector<bool> split(nAxes, false);
    for (std::size_t a = 0; a < nAxes; ++a) {
        col[a] = t.column(errorVarName(axes[a].var));
        if (col[a] < 0)
            throw ValueError(std::string("error table fit: axis ") + errorVarName(axes[a].var) +
                             ": expected a column of the sweep table, found none");
        split[a] = true;  // every row's value is a node: a split
        for (Index r = 0; r < t.data.rows() && split[a]; ++r)
            split[a] = std::find(axes[a].values.begin(), axes[a].values.end(), t.data(r, col[a])) !=
                       axes[a].values.end();
    }
    // Parameters: one per node of every continuous axis.
    std::vector<Index> offset(nAxes, -1);
    Index params = 0;
    for (std::size_t a = 0; a < nAxes; ++a) {
        if (split[a]) continue;
        offset[a] = params;
        params += static_cast<Index>(axes[a].values.size());
    }
    // Rows by split cell (the split axes' node indices, row-major).
    std::map<std::vector<std::size_t>, std::vector<Index>> cells;
    int nonFinite = 0;
    for (Index r = 0; r < t.data.rows(); ++r) {
        if (!std::isfinite(t.data(r, yc))) {
            ++nonFinite;
            continue;
        }
        std::vector<std::size_t> key;
        for (std::size_t a = 0; a < nAxes; ++a)
            if (split[a])
                key.push_back(
                    sz(std::find(axes[a].values.begin(), axes[a].values.end(), t.data(r, col[a])) -
                       axes[a].values.begin()));
        cells[key].push_back(r);
    }
    const double floor = o.floorPercent / 100;
    std::map<std::vector<std::size_t>, std::pair<Eigen::VectorXd, double>> fits;
    std::vector<double> ratios;
    int covered = 0, used = 0;
    for (const auto& [key, rows] : cells) {
        if (static_cast<Index>(rows.size()) < params + 1)
            throw ValueError("error table fit: a split of " + std::to_string(rows.size()) +
                             " rows: expected more rows than the " + std::to_string(params) +
                             " parameters (fewer axes or nodes, or more samples)");
        Eigen::MatrixXd normal = Eigen::MatrixXd::Zero(params, params);
        Eigen::VectorXd rhs = Eigen::VectorXd::Zero(params);
        std::vector<std::vector<std::pair<Index, double>>> basis(rows.size());
        Eigen::VectorXd y(static_cast<Index>(rows.size()));
        for (std::size_t i = 0; i < rows.size(); ++i) {
            const Index r = rows[i];
            y(static_cast<Index>(i)) = std::log(std::max(t.data(r, yc), floor));
            for (std::size_t a = 0; a < nAxes; ++a) {
                if (split[a]) continue;
                const auto [k, w] = hat(axes[a].values, t.data(r, col[a]));
                basis[i].emplace_back(offset[a] + static_cast<Index>(k), 1 - w);
                basis[i].emplace_back(offset[a] + static_cast<Index>(k) + 1, w);
            }
            for (const auto& [p, wp] : basis[i]) {
                rhs(p) += wp * y(static_cast<Index>(i));
                for (const auto& [q, wq] : basis[i]) normal(p, q) += wp * wq;
            }
        }
        const double lambda = o.smoothing * static_cast<double>(rows.size()) / 100;
        for (std::size_t a = 0; a < nAxes; ++a) {
            if (split[a]) continue;
            for (Index k = 1; k + 1 < static_cast<Index>(axes[a].values.size()); ++k) {
                // The change of slope at node k (divided differences, scaled by the mean
                // spacing: 1, -2, 1 on even nodes), so a linear function costs nothing.
                const Index p[3] = {offset[a] + k - 1, offset[a] + k, offset[a] + k + 1};
                const std::vector<double>& v = axes[a].values;
                const double h0 = v[sz(k)] - v[sz(k - 1)], h1 = v[sz(k + 1)] - v[sz(k)];
                const double m = 0.5 * (h0 + h1);
                const double d[3] = {m / h0, -m / h0 - m / h1, m / h1};
                for (int i = 0; i < 3; ++i)
                    for (int j = 0; j < 3; ++j) normal(p[i], p[j]) += lambda * d[i] * d[j];
            }
        }
        normal.diagonal().array() += 1e-9 * static_cast<double>(rows.size());
        const Eigen::VectorXd c = normal.ldlt().solve(rhs);
        std::vector<double> residual(rows.size());
        for (std::size_t i = 0; i < rows.size(); ++i) {
            double fit = 0;
            for (const auto& [p, w] : basis[i]) fit += w * c(p);
            residual[i] = y(static_cast<Index>(i)) - fit;
        }
        const double q = quantileOf(residual, o.quantile);
        fits[key] = {c, q};
        for (std::size_t i = 0; i < rows.size(); ++i) {
            const double err = std::max(t.data(rows[i], yc), floor);
            const double est = std::exp(y(static_cast<Index>(i)) - residual[i] + q);
            covered += est >= err;
            ratios.push_back(est / err);
            ++used;
        }
    }
    // The grid, row-major: each node's split cell and its continuous coordinates.
    std::vector<double> values(shape.errorPercent().size());
    std::vector<std::size_t> idx(nAxes, 0);
    for (std::size_t n = 0; n < values.size(); ++n) {
        std::size_t rem = n;
        for (std::size_t a = nAxes; a-- > 0;) {
            idx[a] = rem % axes[a].values.size();
            rem /= axes[a].values.size();
        }
        std::vector<std::size_t> key;
        double fit = 0;
        for (std::size_t a = 0; a < nAxes; ++a) {
            if (split[a]) key.push_back(idx[a]);
        }
        const auto it = fits.find(key);
        if (it == fits.end())
            throw ValueError("error table fit: a split value has no rows in the sweep table");
        for (std::size_t a = 0; a < nAxes; ++a)
            if (!split[a]) fit += it->second.first(offset[a] + static_cast<Index>(idx[a]));
        values[n] = 100 * std::exp(fit + it->second.second);
    }
    ErrorTable out(std::move(axes), std::move(values), "error table fit");
    out.response = o.response;
    out.quantile = o.quantile;
    const int cc = t.column("coupling");
    out.coupling = cc >= 0 && t.data.rows() > 0 && t.data.col(cc).minCoeff() > 0 ? 1 : 0;
    out.provenance = provenance;
    if (report) {
        report->rowsUsed = used;
        report->rowsNonFinite = nonFinite;
        report->coverage = used ? static_cast<double>(covered) / used : 0;
        std::sort(ratios.begin(), ratios.end());
        report->medianRatio = ratios.empty() ? 0 : ratios[ratios.size() / 2];
    }
    return out;
}

}  // namespace palp::haptics
