#include "palp/studies/scalar_map.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <sstream>
#include <utility>

#include "in_contact.h"
#include "map_util.h"
#include "palp/base/error.h"

namespace palp::haptics {

namespace {

bool finite(const Eigen::Vector3d& v) { return v.allFinite(); }

}  // namespace

int MapPlane::cols() const noexcept {
    return std::max(1, static_cast<int>(std::lround(extentU / pixelM)));
}
int MapPlane::rows() const noexcept {
    return std::max(1, static_cast<int>(std::lround(extentV / pixelM)));
}

bool MapPlane::pixelOf(const Eigen::Vector3d& world, int& col, int& row) const noexcept {
    const Eigen::Vector3d r = world - centre;
    const double a = (r.dot(u) + 0.5 * cols() * pixelM) / pixelM;
    const double b = (r.dot(v) + 0.5 * rows() * pixelM) / pixelM;
    if (!(a >= 0 && b >= 0 && a < cols() && b < rows())) return false;
    col = static_cast<int>(a);
    row = static_cast<int>(b);
    return true;
}

Eigen::Vector3d MapPlane::pixelCentre(int col, int row) const noexcept {
    return centre + ((col + 0.5) * pixelM - 0.5 * cols() * pixelM) * u +
           ((row + 0.5) * pixelM - 0.5 * rows() * pixelM) * v;
}

void validateMapPlane(const MapPlane& plane) {
    auto bad = [](const std::string& field, const std::string& expected, double found) {
        std::ostringstream s;
        s << "map plane: expected " << field << " " << expected << ", found " << found;
        throw ValueError(s.str());
    };
    if (!finite(plane.centre)) bad("centre", "finite", plane.centre.norm());
    if (!(std::abs(plane.u.norm() - 1) < 1e-6)) bad("|u|", "1", plane.u.norm());
    if (!(std::abs(plane.v.norm() - 1) < 1e-6)) bad("|v|", "1", plane.v.norm());
    if (!(std::abs(plane.u.dot(plane.v)) < 1e-6)) bad("u . v", "0", plane.u.dot(plane.v));
    if (!(plane.pixelM > 0 && std::isfinite(plane.pixelM)))
        bad("pixel size (m)", "> 0", plane.pixelM);
    if (!(plane.extentU > 0 && std::isfinite(plane.extentU)))
        bad("extentU (m)", "> 0", plane.extentU);
    if (!(plane.extentV > 0 && std::isfinite(plane.extentV)))
        bad("extentV (m)", "> 0", plane.extentV);
    if (plane.extentU / plane.pixelM > 4096 || plane.extentV / plane.pixelM > 4096) {
        bad("at most 4096 pixels along a side: extent / pixel", "<= 4096",
            std::max(plane.extentU, plane.extentV) / plane.pixelM);
    }
}

const char* mapQuantityName(MapQuantity quantity) noexcept {
    switch (quantity) {
        case MapQuantity::Stiffness:
            return "stiffness";
        case MapQuantity::Force:
            return "force";
        case MapQuantity::Energy:
            return "energy";
    }
    return "?";
}

MapQuantity parseMapQuantity(const std::string& name) {
    if (name == "stiffness") return MapQuantity::Stiffness;
    if (name == "force") return MapQuantity::Force;
    if (name == "energy") return MapQuantity::Energy;
    throw ValueError("map quantity: expected stiffness, force or energy, found '" + name + "'");
}

double mapValue(const Snapshot& s, MapQuantity quantity) noexcept {
    switch (quantity) {
        case MapQuantity::Stiffness:
            return s.stiffness;
        case MapQuantity::Force:
            return s.force.norm();
        case MapQuantity::Energy:
            return s.energyForce.norm() + s.proxyForce.norm();
    }
    return kNaN;
}

ScalarMap::ScalarMap(const MapPlane& plane) : mPlane(plane) {
    validateMapPlane(plane);
    mCols = plane.cols();
    mRows = plane.rows();
    const auto n = static_cast<std::size_t>(mCols) * static_cast<std::size_t>(mRows);
    mSum.assign(n, 0.0);
    mCount.assign(n, 0);
}

void ScalarMap::add(const Eigen::Vector3d& world, double value) noexcept {
    int c = 0, r = 0;
    if (!std::isfinite(value) || !mPlane.pixelOf(world, c, r)) return;
    const auto i =
        static_cast<std::size_t>(r) * static_cast<std::size_t>(mCols) + static_cast<std::size_t>(c);
    mSum[i] += value;
    ++mCount[i];
}

double ScalarMap::at(int col, int row) const noexcept {
    if (col < 0 || row < 0 || col >= mCols || row >= mRows) return kNaN;
    const auto i = static_cast<std::size_t>(row) * static_cast<std::size_t>(mCols) +
                   static_cast<std::size_t>(col);
    return mCount[i] ? mSum[i] / mCount[i] : kNaN;
}

std::uint32_t ScalarMap::count(int col, int row) const noexcept {
    if (col < 0 || row < 0 || col >= mCols || row >= mRows) return 0;
    return mCount[static_cast<std::size_t>(row) * static_cast<std::size_t>(mCols) +
                  static_cast<std::size_t>(col)];
}

void ScalarMap::set(int col, int row, double value) noexcept {
    if (col < 0 || row < 0 || col >= mCols || row >= mRows) return;
    const auto i = static_cast<std::size_t>(row) * static_cast<std::size_t>(mCols) +
                   static_cast<std::size_t>(col);
    mSum[i] = value;
    mCount[i] = 1;
}

void ScalarMap::fillGaps(int passes) {
    for (int p = 0; p < passes; ++p) {
        std::vector<std::pair<int, int>> cells;
        std::vector<double> values;
        for (int r = 0; r < mRows; ++r) {
            for (int c = 0; c < mCols; ++c) {
                if (count(c, r)) continue;
                double sum = 0;
                int n = 0;
                for (int dr = -1; dr <= 1; ++dr) {
                    for (int dc = -1; dc <= 1; ++dc) {
                        const double x = at(c + dc, r + dr);
                        if (std::isfinite(x)) {
                            sum += x;
                            ++n;
                        }
                    }
                }
                if (n) {
                    cells.emplace_back(c, r);
                    values.push_back(sum / n);
                }
            }
        }
        if (cells.empty()) return;
        for (std::size_t i = 0; i < cells.size(); ++i)
            set(cells[i].first, cells[i].second, values[i]);
    }
}

void ScalarMap::range(double& lo, double& hi) const noexcept {
    lo = std::numeric_limits<double>::infinity();
    hi = -lo;
    for (int r = 0; r < mRows; ++r) {
        for (int c = 0; c < mCols; ++c) {
            const double x = at(c, r);
            if (std::isfinite(x)) {
                lo = std::min(lo, x);
                hi = std::max(hi, x);
            }
        }
    }
    if (lo > hi) lo = hi = kNaN;
}

std::vector<double> ScalarMap::finiteValues() const {
    std::vector<double> out;
    for (int r = 0; r < mRows; ++r) {
        for (int c = 0; c < mCols; ++c) {
            const double x = at(c, r);
            if (std::isfinite(x)) out.push_back(x);
        }
    }
    return out;
}

const char* mapAnchorName(MapAnchor anchor) noexcept {
    return anchor == MapAnchor::Proxy ? "proxy" : "ray-end";
}

MapAnchor parseMapAnchor(const std::string& name) {
    if (name == "proxy") return MapAnchor::Proxy;
    if (name == "ray-end") return MapAnchor::RayEnd;
    throw ValueError("map anchor: expected proxy or ray-end, found '" + name + "'");
}

ScalarMap binSnapshots(std::span<const Snapshot> snapshots, const MapPlane& plane,
                       MapQuantity quantity, bool contactOnly, MapAnchor anchor) {
    ScalarMap map(plane);
    for (const Snapshot& s : snapshots) {
        if (contactOnly && !(detail::inContact(s) && (s.rays > 0 || s.mode == CouplingMode::VC)))
            continue;
        Eigen::Vector3d at = s.proxy;
        if (anchor == MapAnchor::RayEnd) {
            const Eigen::Vector3d d = s.probe - s.proxy;
            const double n = d.norm();
            if (!(n > 0) || !std::isfinite(s.rayLength)) continue;
            at = s.proxy + (s.rayLength / n) * d;
        }
        map.add(at, mapValue(s, quantity));
    }
    return map;
}

}  // namespace palp::haptics
