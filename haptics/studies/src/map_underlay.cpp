#include "palp/studies/map_underlay.h"

#include <openvdb/tools/Interpolation.h>
#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <sstream>
#include <string>

#include "map_util.h"
#include "palp/base/error.h"
#include "palp/kernels/embree_scene.h"

namespace palp::haptics {

namespace {

void checkProjection(const char* what, const MapPlane& plane, const Eigen::Vector3d& press,
                     double lengthM) {
    const auto bad = [&](const std::string& field, const std::string& expected, double found) {
        std::ostringstream m;
        m << what << ": expected " << field << " " << expected << ", found " << found;
        throw ValueError(m.str());
    };
    if (!(std::abs(press.norm() - 1) < 1e-6)) bad("|press|", "1", press.norm());
    if (!(std::abs(press.dot(plane.u)) < 1e-6)) bad("press . u", "0", press.dot(plane.u));
    if (!(std::abs(press.dot(plane.v)) < 1e-6)) bad("press . v", "0", press.dot(plane.v));
    if (!(lengthM > 0 && std::isfinite(lengthM))) bad("a length", "> 0 (m)", lengthM);
}

}  // namespace

ScalarMap skinDepthMap(const kernels::EmbreeScene& surfaces, const MapPlane& plane,
                       const Eigen::Vector3d& press, double lengthM) {
    checkProjection("skin depth map", plane, press, lengthM);
    ScalarMap map(plane);
    if (surfaces.empty() || !surfaces.committed()) return map;
    constexpr double kBefore = 0.01;  // rays start this far outside the plane, m
    for (int row = 0; row < map.rows(); ++row) {
        for (int col = 0; col < map.cols(); ++col) {
            const Eigen::Vector3d origin = plane.pixelCentre(col, row) - kBefore * press;
            kernels::MeshHit hit;
            if (kernels::intersectOne(surfaces, origin, press, 0.0f,
                                      static_cast<float>(lengthM + kBefore), kernels::kMaskSurface,
                                      hit)) {
                map.set(col, row, (hit.t - kBefore) * 1e3);
            }
        }
    }
    return map;
}

ScalarMap mipMap(const volume::Volume& vol, const MapPlane& plane, const Eigen::Vector3d& press,
                 double lengthM, const ScalarMap* fromMm) {
    checkProjection("MIP map", plane, press, lengthM);
    if (fromMm && (fromMm->cols() != plane.cols() || fromMm->rows() != plane.rows())) {
        throw ValueError("MIP map: expected start depths over " + std::to_string(plane.cols()) +
                         " x " + std::to_string(plane.rows()) + " pixels, found " +
                         std::to_string(fromMm->cols()) + " x " + std::to_string(fromMm->rows()));
    }
    ScalarMap map(plane);
    if (!vol.grid) return map;
    const openvdb::BBoxd box = vol.worldBounds();
    const double step = vol.voxelSize();
    const int n = static_cast<int>(std::ceil(lengthM / step)) + 1;
    std::vector<double> out(
        static_cast<std::size_t>(map.cols()) * static_cast<std::size_t>(map.rows()), kNaN);
    const int cols = map.cols();
    tbb::parallel_for(
        tbb::blocked_range<int>(0, map.rows()), [&](const tbb::blocked_range<int>& r) {
            const openvdb::tools::GridSampler<openvdb::FloatGrid, openvdb::tools::BoxSampler>
                sampler(*vol.grid);
            for (int row = r.begin(); row < r.end(); ++row) {
                for (int col = 0; col < cols; ++col) {
                    const double from = fromMm ? fromMm->at(col, row) * 1e-3 : 0.0;
                    if (!std::isfinite(from)) continue;
                    const Eigen::Vector3d p0 = plane.pixelCentre(col, row) + from * press;
                    double best = -std::numeric_limits<double>::infinity();
                    for (int k = 0; k < n; ++k) {
                        const Eigen::Vector3d p = p0 + (k * step) * press;
                        const openvdb::Vec3d w(p.x(), p.y(), p.z());
                        if (!box.isInside(w)) continue;
                        best = std::max(best, static_cast<double>(sampler.wsSample(w)));
                    }
                    if (std::isfinite(best))
                        out[static_cast<std::size_t>(row) * static_cast<std::size_t>(cols) +
                            static_cast<std::size_t>(col)] = best;
                }
            }
        });
    for (int row = 0; row < map.rows(); ++row) {
        for (int col = 0; col < cols; ++col) {
            const double v = out[static_cast<std::size_t>(row) * static_cast<std::size_t>(cols) +
                                 static_cast<std::size_t>(col)];
            if (std::isfinite(v)) map.set(col, row, v);
        }
    }
    return map;
}

}  // namespace palp::haptics
