// Partial rank correlation coefficients and reading a sweep table (prcc.h).
#include "palp/studies/prcc.h"

#include <Eigen/QR>
#include <algorithm>
#include <boost/math/distributions/normal.hpp>
#include <boost/math/distributions/students_t.hpp>
#include <cmath>
#include <fstream>
#include <limits>
#include <nlohmann/json.hpp>
#include <numeric>
#include <sstream>

#include "palp/base/error.h"

namespace palp::haptics {

namespace fs = std::filesystem;

Eigen::VectorXd averageRanks(const Eigen::VectorXd& v) {
    const auto n = static_cast<std::size_t>(v.size());
    std::vector<Eigen::Index> order(n);
    std::iota(order.begin(), order.end(), Eigen::Index{0});
    std::stable_sort(order.begin(), order.end(),
                     [&](Eigen::Index a, Eigen::Index b) { return v[a] < v[b]; });
    Eigen::VectorXd r(v.size());
    std::size_t i = 0;
    while (i < n) {
        std::size_t j = i + 1;
        while (j < n && v[order[j]] == v[order[i]]) ++j;
        const double rank = 0.5 * static_cast<double>(i + 1 + j);  // mean of positions i+1..j
        for (std::size_t k = i; k < j; ++k) r[order[k]] = rank;
        i = j;
    }
    return r;
}

std::vector<PrccEntry> partialRankCorrelation(const Eigen::MatrixXd& x, const Eigen::VectorXd& y,
                                              const std::vector<std::string>& names, double level) {
    const Eigen::Index n = x.rows(), m = x.cols();
    if (y.size() != n || static_cast<Eigen::Index>(names.size()) != m || m < 1)
        throw ValueError("PRCC: expected x of n x m, y of n and m names, found " +
                         std::to_string(n) + " x " + std::to_string(m) + ", " +
                         std::to_string(y.size()) + ", " + std::to_string(names.size()));
    const Eigen::Index k = m - 1;
    if (n <= m + 3)
        throw ValueError("PRCC: expected more than " + std::to_string(m + 3) + " rows for " +
                         std::to_string(m) + " variables, found " + std::to_string(n));
    if (!(level > 0.0 && level < 1.0))
        throw ValueError("PRCC: confidence level: expected (0, 1), found " + std::to_string(level));
    Eigen::MatrixXd rx(n, m);
    for (Eigen::Index j = 0; j < m; ++j) {
        if ((x.col(j).array() == x(0, j)).all())
            throw ValueError("PRCC: variable '" + names[static_cast<std::size_t>(j)] +
                             "' is constant: nothing to correlate");
        rx.col(j) = averageRanks(x.col(j));
    }
    const Eigen::VectorXd ry = averageRanks(y);
    const double dof = static_cast<double>(n - 2 - k);
    const boost::math::students_t t(dof);
    const double z = boost::math::quantile(boost::math::normal(), 0.5 + 0.5 * level);
    std::vector<PrccEntry> out;
    for (Eigen::Index j = 0; j < m; ++j) {
        // The other variables' ranks with an intercept column.
        Eigen::MatrixXd a(n, m);
        a.col(0).setOnes();
        for (Eigen::Index c = 0, col = 1; c < m; ++c)
            if (c != j) a.col(col++) = rx.col(c);
        const Eigen::ColPivHouseholderQR<Eigen::MatrixXd> qr(a);
        const Eigen::VectorXd ex = rx.col(j) - a * qr.solve(rx.col(j));
        const Eigen::VectorXd ey = ry - a * qr.solve(ry);
        PrccEntry e;
        e.name = names[static_cast<std::size_t>(j)];
        e.r = ex.dot(ey) / std::sqrt(ex.squaredNorm() * ey.squaredNorm());
        const double r2 = std::min(e.r * e.r, 1.0);
        e.t = r2 < 1.0 ? e.r * std::sqrt(dof / (1.0 - r2))
                       : std::copysign(std::numeric_limits<double>::infinity(), e.r);
        e.p = std::isfinite(e.t) ? 2.0 * boost::math::cdf(boost::math::complement(t, std::abs(e.t)))
                                 : 0.0;
        const double zr = std::atanh(std::clamp(e.r, -1.0 + 1e-16, 1.0 - 1e-16));
        const double se = 1.0 / std::sqrt(static_cast<double>(n - 3 - k));
        e.lower = std::tanh(zr - z * se);
        e.upper = std::tanh(zr + z * se);
        out.push_back(e);
    }
    return out;
}

int SweepTable::column(const std::string& name) const {
    const auto it = std::find(names.begin(), names.end(), name);
    return it == names.end() ? -1 : static_cast<int>(it - names.begin());
}

namespace prcc_impl {

std::vector<std::string> split(const std::string& line) {
    std::vector<std::string> out;
    std::string cell;
    std::istringstream in(line);
    while (std::getline(in, cell, ',')) out.push_back(cell);
    if (!line.empty() && line.back() == ',') out.emplace_back();
    return out;
}

}  // namespace prcc_impl

using namespace prcc_impl;

SweepTable readSweepTable(const fs::path& csv) {
    std::ifstream in(csv);
    if (!in) throw IoError(csv.string() + ": cannot read the sweep table");
    SweepTable t;
    std::string line;
    if (!std::getline(in, line) || line.empty())
        throw FormatError(csv.string() + ": expected a header line, found nothing");
    t.names = split(line);
    const std::size_t cols = t.names.size();
    std::vector<std::vector<double>> rows;
    int lineNo = 1;
    while (std::getline(in, line)) {
        ++lineNo;
        if (line.empty()) continue;
        const auto cells = split(line);
        if (cells.size() != cols)
            throw FormatError(csv.string() + ": line " + std::to_string(lineNo) + ": expected " +
                              std::to_string(cols) + " fields, found " +
                              std::to_string(cells.size()));
        std::vector<double> row(cols);
        for (std::size_t c = 0; c < cols; ++c) {
            char* end = nullptr;
            row[c] = std::strtod(cells[c].c_str(), &end);
            if (cells[c].empty() || *end != '\0')
                throw FormatError(csv.string() + ": line " + std::to_string(lineNo) + ", column '" +
                                  t.names[c] + "': expected a number, found '" + cells[c] + "'");
        }
        rows.push_back(std::move(row));
    }
    t.data.resize(static_cast<Eigen::Index>(rows.size()), static_cast<Eigen::Index>(cols));
    for (std::size_t r = 0; r < rows.size(); ++r)
        for (std::size_t c = 0; c < cols; ++c)
            t.data(static_cast<Eigen::Index>(r), static_cast<Eigen::Index>(c)) = rows[r][c];
    t.units.assign(cols, "1");
    t.roles.assign(cols, "variable");
    t.descriptions = t.names;
    fs::path sidecar = csv;
    sidecar.replace_extension(".json");
    if (fs::exists(sidecar)) {
        std::ifstream s(sidecar);
        nlohmann::json j;
        try {
            j = nlohmann::json::parse(s);
        } catch (const nlohmann::json::parse_error& e) {
            throw FormatError(sidecar.string() + ": not a JSON sidecar: " + e.what());
        }
        if (!j.contains("columns") || !j["columns"].is_array() || j["columns"].size() != cols)
            throw FormatError(sidecar.string() + ": field 'columns': expected " +
                              std::to_string(cols) + " entries (the table's columns)");
        for (std::size_t c = 0; c < cols; ++c) {
            const auto& col = j["columns"][c];
            if (col.value("name", "") != t.names[c])
                throw FormatError(sidecar.string() + ": field 'columns[" + std::to_string(c) +
                                  "].name': expected '" + t.names[c] + "' (the table's), found '" +
                                  col.value("name", "") + "'");
            t.units[c] = col.value("unit", "1");
            t.roles[c] = col.value("role", "variable");
            t.descriptions[c] = col.value("description", t.names[c]);
        }
    }
    return t;
}

std::vector<PrccEntry> sweepPrcc(const SweepTable& table, const std::string& response, double level,
                                 int* dropped, int* used) {
    const int yc = table.column(response);
    if (yc < 0)
        throw ValueError("--response: expected a column of the table, found '" + response + "'");
    std::vector<int> xc;
    std::vector<std::string> names;
    std::vector<Eigen::Index> rows;
    for (Eigen::Index r = 0; r < table.data.rows(); ++r)
        if (std::isfinite(table.data(r, yc))) rows.push_back(r);
    for (int c = 0; c < static_cast<int>(table.names.size()); ++c) {
        const auto& role = table.roles[static_cast<std::size_t>(c)];
        const auto& name = table.names[static_cast<std::size_t>(c)];
        if ((role != "variable" && role != "derived") || c == yc) continue;
        if (name == "contact_node" || name == "primary_free_nodes") continue;
        bool varies = false;
        for (auto r : rows) varies = varies || table.data(r, c) != table.data(rows.front(), c);
        if (!varies) continue;
        xc.push_back(c);
        names.push_back(name);
    }
    if (rows.empty()) throw ValueError("errormap: no row has a finite '" + response + "'");
    Eigen::MatrixXd x(static_cast<Eigen::Index>(rows.size()), static_cast<Eigen::Index>(xc.size()));
    Eigen::VectorXd y(static_cast<Eigen::Index>(rows.size()));
    for (std::size_t i = 0; i < rows.size(); ++i) {
        for (std::size_t j = 0; j < xc.size(); ++j)
            x(static_cast<Eigen::Index>(i), static_cast<Eigen::Index>(j)) =
                table.data(rows[i], xc[j]);
        y[static_cast<Eigen::Index>(i)] = table.data(rows[i], yc);
    }
    if (dropped) *dropped = static_cast<int>(table.data.rows()) - static_cast<int>(rows.size());
    if (used) *used = static_cast<int>(rows.size());
    auto out = partialRankCorrelation(x, y, names, level);
    for (std::size_t j = 0; j < out.size(); ++j)
        out[j].unit = table.units[static_cast<std::size_t>(xc[j])];
    return out;
}

}  // namespace palp::haptics
