#pragma once
// Analytic shapes for the ray kernel tests: signed distance functions, exact ray intersections,
// and their VDB volumes (a linear ramp of values across the surface).
#include <openvdb/openvdb.h>

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <functional>
#include <limits>

namespace palp::test {

inline constexpr double kVoxel = 0.5e-3;    // metres
inline constexpr float kInside = 1000.0f;   // value deep inside a shape
inline constexpr float kIso = 500.0f;       // the surface's value
inline constexpr double kRampVoxels = 2.0;  // half-width of the ramp across the surface, voxels

/// Volume of a shape given by its signed distance (metres, negative inside): value
/// kInside * clamp(0.5 - sdf / (2 w), 0, 1), w = kRampVoxels voxels; background 0 (inactive).
/// @p lo, @p hi: index box to fill.
inline openvdb::FloatGrid::Ptr shapeVolume(const std::function<double(const Eigen::Vector3d&)>& sdf,
                                           openvdb::Coord lo, openvdb::Coord hi) {
    openvdb::initialize();
    auto grid = openvdb::FloatGrid::create(0.0f);
    grid->setTransform(openvdb::math::Transform::createLinearTransform(kVoxel));
    auto acc = grid->getAccessor();
    const double w = kRampVoxels * kVoxel;
    for (int i = lo.x(); i <= hi.x(); ++i)
        for (int j = lo.y(); j <= hi.y(); ++j)
            for (int k = lo.z(); k <= hi.z(); ++k) {
                const Eigen::Vector3d p(i * kVoxel, j * kVoxel, k * kVoxel);
                const double v = kInside * std::clamp(0.5 - sdf(p) / (2 * w), 0.0, 1.0);
                if (v > 0) acc.setValue({i, j, k}, static_cast<float>(v));
            }
    return grid;
}

struct Plane {
    Eigen::Vector3d n;  // unit normal, pointing out
    double c;           // n.x = c on the plane; inside where n.x < c
    double sdf(const Eigen::Vector3d& p) const { return n.dot(p) - c; }
    double hit(const Eigen::Vector3d& o, const Eigen::Vector3d& d) const {
        const double dn = n.dot(d);
        if (sdf(o) <= 0) return 0;
        const double t = (c - n.dot(o)) / dn;
        return dn < 0 ? t : std::numeric_limits<double>::infinity();
    }
};

struct Sphere {
    Eigen::Vector3d centre;
    double radius;
    double sdf(const Eigen::Vector3d& p) const { return (p - centre).norm() - radius; }
    double hit(const Eigen::Vector3d& o, const Eigen::Vector3d& d) const {
        const Eigen::Vector3d oc = o - centre;
        const double b = oc.dot(d), c = oc.squaredNorm() - radius * radius;
        if (c <= 0) return 0;
        const double disc = b * b - c;
        if (disc < 0) return std::numeric_limits<double>::infinity();
        const double t = -b - std::sqrt(disc);
        return t >= 0 ? t : std::numeric_limits<double>::infinity();
    }
};

struct Box {
    Eigen::Vector3d centre, half;
    double sdf(const Eigen::Vector3d& p) const {
        const Eigen::Vector3d q = (p - centre).cwiseAbs() - half;
        return q.cwiseMax(0.0).norm() + std::min(q.maxCoeff(), 0.0);
    }
    double hit(const Eigen::Vector3d& o, const Eigen::Vector3d& d) const {
        double t0 = 0, t1 = std::numeric_limits<double>::infinity();
        for (int a = 0; a < 3; ++a) {
            const double lo = centre[a] - half[a], hi = centre[a] + half[a];
            if (d[a] == 0) {
                if (o[a] < lo || o[a] > hi) return std::numeric_limits<double>::infinity();
                continue;
            }
            double ta = (lo - o[a]) / d[a], tb = (hi - o[a]) / d[a];
            if (ta > tb) std::swap(ta, tb);
            t0 = std::max(t0, ta);
            t1 = std::min(t1, tb);
        }
        return t0 <= t1 ? t0 : std::numeric_limits<double>::infinity();
    }
};

}  // namespace palp::test
