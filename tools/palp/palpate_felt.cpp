#include "palpate_felt.h"

#include <algorithm>
#include <cmath>
#include <numeric>
#include <vector>

namespace palp::tool {

namespace {

/// Average ranks (ties share the mean of their ranks).
std::vector<double> ranks(std::span<const double> x) {
    std::vector<std::size_t> order(x.size());
    std::iota(order.begin(), order.end(), 0);
    std::sort(order.begin(), order.end(),
              [&](std::size_t a, std::size_t b) { return x[a] < x[b]; });
    std::vector<double> r(x.size());
    for (std::size_t i = 0; i < order.size();) {
        std::size_t j = i;
        while (j + 1 < order.size() && x[order[j + 1]] == x[order[i]]) ++j;
        for (std::size_t k = i; k <= j; ++k) r[order[k]] = 0.5 * static_cast<double>(i + j);
        i = j + 1;
    }
    return r;
}

/// Per-cell sums over a frame.
struct Cells {
    int nu = 0, nv = 0;
    double cell = 0;
    std::vector<double> k, length, count;
    std::vector<Eigen::Vector3d> at;
};

}  // namespace

double spearman(std::span<const double> x, std::span<const double> y) {
    const std::vector<double> rx = ranks(x), ry = ranks(y);
    const double n = static_cast<double>(rx.size());
    const double mx = std::accumulate(rx.begin(), rx.end(), 0.0) / n;
    const double my = std::accumulate(ry.begin(), ry.end(), 0.0) / n;
    double sxy = 0, sxx = 0, syy = 0;
    for (std::size_t i = 0; i < rx.size(); ++i) {
        sxy += (rx[i] - mx) * (ry[i] - my);
        sxx += (rx[i] - mx) * (rx[i] - mx);
        syy += (ry[i] - my) * (ry[i] - my);
    }
    return sxx > 0 && syy > 0 ? sxy / std::sqrt(sxx * syy) : std::nan("");
}

nlohmann::json feltSummary(std::span<const haptics::Snapshot> snaps, const PathFrame& f,
                           double cellM, double pressedFrom) {
    Cells c;
    c.cell = cellM;
    c.nu = std::max(1, static_cast<int>(std::floor(f.extentU / cellM)));
    c.nv = std::max(1, static_cast<int>(std::floor(f.extentV / cellM)));
    const auto n = static_cast<std::size_t>(c.nu) * static_cast<std::size_t>(c.nv);
    c.k.assign(n, 0.0);
    c.length.assign(n, 0.0);
    c.count.assign(n, 0.0);
    c.at.assign(n, Eigen::Vector3d::Zero());
    for (const haptics::Snapshot& s : snaps) {
        // In contact (as the run summary counts it), on the path proper.
        if (s.timeSeconds < pressedFrom || !(s.contactCount > 0 || s.distance > 1e-6)) continue;
        const Eigen::Vector3d r = s.proxy - f.centre;
        const int i = static_cast<int>(std::floor(r.dot(f.u) / cellM + 0.5 * c.nu));
        const int j = static_cast<int>(std::floor(r.dot(f.v) / cellM + 0.5 * c.nv));
        if (i < 0 || j < 0 || i >= c.nu || j >= c.nv) continue;
        const auto k = static_cast<std::size_t>(j) * static_cast<std::size_t>(c.nu) +
                       static_cast<std::size_t>(i);
        c.k[k] += s.stiffness;
        c.length[k] += s.rayLength;
        c.count[k] += 1;
        c.at[k] += s.proxy;
    }
    std::vector<double> ks, ls;
    std::size_t best = n;
    for (std::size_t k = 0; k < n; ++k) {
        if (c.count[k] < 3) continue;
        c.k[k] /= c.count[k];
        c.length[k] /= c.count[k];
        c.at[k] /= c.count[k];
        ks.push_back(c.k[k]);
        ls.push_back(c.length[k]);
        // Ties (a clamped stiffness) go to the cell with the hard structure nearest the skin.
        if (best == n || c.k[k] > c.k[best] ||
            (c.k[k] == c.k[best] && c.length[k] < c.length[best]))
            best = k;
    }
    nlohmann::json j = {{"cell_mm", cellM * 1e3}, {"cells", ks.size()}};
    if (best == n) return j;
    int near = 0;
    for (std::size_t k = 0; k < n; ++k)
        if (c.count[k] >= 3 && c.k[k] >= 0.99 * c.k[best]) ++near;
    const Eigen::Vector3d at = c.at[best] * 1e3;
    const int bi = static_cast<int>(best % static_cast<std::size_t>(c.nu));
    const int bj = static_cast<int>(best / static_cast<std::size_t>(c.nu));
    j["stiffest"] = {
        {"stiffness_npm", c.k[best]},
        {"at_mm", {at.x(), at.y(), at.z()}},
        {"lateral_mm",
         {((bi + 0.5) - 0.5 * c.nu) * cellM * 1e3, ((bj + 0.5) - 0.5 * c.nv) * cellM * 1e3}},
        {"hard_depth_mm", c.length[best] * 1e3},
        {"cells_within_1_percent", near}};
    if (ks.size() >= 3) {
        const double rho = spearman(ks, ls);
        j["stiffness_vs_hard_depth_spearman"] = std::isfinite(rho) ? nlohmann::json(rho) : nullptr;
    }
    return j;
}

}  // namespace palp::tool
