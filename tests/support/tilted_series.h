#pragma once
/// @file
/// A CT-like tilted axial series of any size made in memory, for the resampler's scale test and
/// bench/volume/bench_convert: an ellipsoidal "head" (soft tissue, 40 HU, with a smooth ripple so
/// that interpolation matters) inside a 6 mm 1000 HU shell, air (-1000 HU) around, filling ~70 %
/// of the field of view. Slices are tilted by the gantry like palp::volume::SliceGeometry: row
/// direction (1, 0, 0), column direction (0, cos t, -sin t), stacked along z by gap / cos t.

#include <cmath>
#include <string>

#include "palp/volume/slice_stack.h"

namespace palp::test {

/// @p cols x @p rows pixels of @p pixel metres, @p slices slices @p gap metres apart along the
/// normal, tilted by @p tiltDeg degrees. Deterministic.
inline volume::SliceStack tiltedSeries(int cols, int rows, int slices, double pixel, double gap,
                                       double tiltDeg) {
    volume::SliceStack s;
    s.info.modality = "CT";
    s.info.valueUnits = "HU";
    s.info.sourceFormat = "generated";
    const double t = tiltDeg * M_PI / 180.0;
    const Eigen::Vector3d colDir(1, 0, 0), rowDir(0, std::cos(t), -std::sin(t));
    const Eigen::Vector3d centre(0.5 * (cols - 1) * pixel, 0.5 * (rows - 1) * pixel,
                                 0.5 * (slices - 1) * gap / std::cos(t));
    const Eigen::Vector3d semi(0.42 * cols * pixel, 0.42 * rows * pixel,
                               0.45 * slices * gap / std::cos(t));
    s.slices.resize(static_cast<std::size_t>(slices));
    for (int k = 0; k < slices; ++k) {
        volume::Slice& sl = s.slices[static_cast<std::size_t>(k)];
        sl.cols = cols;
        sl.rows = rows;
        sl.colStep = pixel * colDir;
        sl.rowStep = pixel * rowDir;
        // Table moves along z; the slice plane through (0, 0, z_k) with the tilted normal.
        sl.position = Eigen::Vector3d(0, 0, k * gap / std::cos(t));
        sl.source = "generated slice " + std::to_string(k);
        sl.values.resize(static_cast<std::size_t>(cols) * static_cast<std::size_t>(rows));
        for (int r = 0; r < rows; ++r) {
            for (int c = 0; c < cols; ++c) {
                const Eigen::Vector3d p = sl.position + c * sl.colStep + r * sl.rowStep;
                const Eigen::Vector3d q = (p - centre).cwiseQuotient(semi);
                const double rho = q.norm();
                const double shell = 0.006 / semi.minCoeff();
                float v = -1000.0f;
                if (rho < 1.0 - shell) {
                    v = static_cast<float>(40.0 + 25.0 * std::sin(900.0 * p.x()) *
                                                      std::cos(700.0 * p.y() + 500.0 * p.z()));
                } else if (rho < 1.0) {
                    v = 1000.0f;
                }
                sl.values[static_cast<std::size_t>(r) * static_cast<std::size_t>(cols) +
                          static_cast<std::size_t>(c)] = v;
            }
        }
    }
    return s;
}

}  // namespace palp::test
