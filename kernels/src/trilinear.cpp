#include "palp/kernels/trilinear.h"

#include <cmath>

namespace palp::kernels {

float sampleIndex(const openvdb::FloatGrid::ConstAccessor& acc,
                  const openvdb::Vec3d& indexPos) noexcept {
    const double fx = std::floor(indexPos.x());
    const double fy = std::floor(indexPos.y());
    const double fz = std::floor(indexPos.z());
    const auto i = static_cast<openvdb::Int32>(fx);
    const auto j = static_cast<openvdb::Int32>(fy);
    const auto k = static_cast<openvdb::Int32>(fz);
    const double tx = indexPos.x() - fx;
    const double ty = indexPos.y() - fy;
    const double tz = indexPos.z() - fz;
    auto v = [&](int a, int b, int c) {
        return static_cast<double>(acc.getValue(openvdb::Coord(i + a, j + b, k + c)));
    };
    const double c00 = v(0, 0, 0) * (1 - tx) + v(1, 0, 0) * tx;
    const double c10 = v(0, 1, 0) * (1 - tx) + v(1, 1, 0) * tx;
    const double c01 = v(0, 0, 1) * (1 - tx) + v(1, 0, 1) * tx;
    const double c11 = v(0, 1, 1) * (1 - tx) + v(1, 1, 1) * tx;
    const double c0 = c00 * (1 - ty) + c10 * ty;
    const double c1 = c01 * (1 - ty) + c11 * ty;
    return static_cast<float>(c0 * (1 - tz) + c1 * tz);
}

float sampleWorld(const openvdb::FloatGrid::ConstAccessor& acc,
                  const openvdb::math::Transform& xform, const openvdb::Vec3d& worldPos) noexcept {
    return sampleIndex(acc, xform.worldToIndex(worldPos));
}

}  // namespace palp::kernels
