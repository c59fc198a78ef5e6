#include "palp/kernels/ray_bundle.h"

#include <cmath>
#include <numbers>
#include <string>

#include "palp/base/bounds.h"
#include "palp/base/validate.h"

namespace palp::kernels {

namespace {

bool finiteVec3(const Eigen::Vector3d& v) noexcept {
    return std::isfinite(v.x()) && std::isfinite(v.y()) && std::isfinite(v.z());
}

void setRay(RayBundle& b, int r, const Eigen::Vector3d& o, const Eigen::Vector3d& d, double len,
            double w) noexcept {
    const auto i = static_cast<std::size_t>(r);
    b.ox[i] = static_cast<float>(o.x());
    b.oy[i] = static_cast<float>(o.y());
    b.oz[i] = static_cast<float>(o.z());
    b.dx[i] = static_cast<float>(d.x());
    b.dy[i] = static_cast<float>(d.y());
    b.dz[i] = static_cast<float>(d.z());
    b.length[i] = static_cast<float>(len);
    b.weight[i] = static_cast<float>(w);
}

std::array<double, 9> gather(const RayBundle& b, std::span<const double> v, bool sphere) noexcept {
    std::array<double, 9> k{};
    for (int j = -1; j <= 1; ++j)
        for (int i = -1; i <= 1; ++i) {
            const int r = sphere ? b.sphereRay(i, j) : b.surfaceRay(i, j);
            k[static_cast<std::size_t>((j + 1) * 3 + (i + 1))] = v[static_cast<std::size_t>(r)];
        }
    return k;
}

}  // namespace

void validateBundleParams(const BundleParams& p) {
    const double halfPi = std::numbers::pi / 2;
    requireWithin("bundle length", p.length, bounds::kLength);
    if (p.ringCount < 0 || p.ringCount > kMaxRingRays)
        throwExpected("bundle ringCount", "0.." + std::to_string(kMaxRingRays),
                      std::to_string(p.ringCount));
    if (p.ringCount > 0 && !(p.ringHalfAngle > 0 && p.ringHalfAngle < halfPi))
        throwExpected("bundle ringHalfAngle", "an angle in (0, pi/2) rad",
                      formatValue(p.ringHalfAngle));
    if (p.ringCount > 0) requirePositive("bundle ringWeightSigma", p.ringWeightSigma, "rad");
    if (!(p.sobelAngle > 0 && p.sobelAngle < halfPi))
        throwExpected("bundle sobelAngle", "an angle in (0, pi/2) rad", formatValue(p.sobelAngle));
    requireWithin("bundle surfaceOffset", p.surfaceOffset, bounds::kSpacing);
}

void orthonormalBasis(const Eigen::Vector3d& d, Eigen::Vector3d& e1, Eigen::Vector3d& e2) noexcept {
    const double sign = std::copysign(1.0, d.z());
    const double a = -1.0 / (sign + d.z());
    const double b = d.x() * d.y() * a;
    e1 = Eigen::Vector3d(1.0 + sign * d.x() * d.x() * a, sign * b, -sign * d.x());
    e2 = Eigen::Vector3d(b, sign + d.y() * d.y() * a, -d.y());
}

bool generateBundle(const Eigen::Vector3d& origin, const Eigen::Vector3d& direction,
                    const Eigen::Vector3d& tangent1, const Eigen::Vector3d& tangent2,
                    const BundleParams& params, RayBundle& out) noexcept {
    out.count = 0;
    out.valid = false;
    out.ringCount = 0;
    const double n = direction.norm();
    const bool paramsOk = std::isfinite(params.length) && params.length >= 0 &&
                          params.ringCount >= 0 && params.ringCount <= kMaxRingRays &&
                          std::isfinite(params.sobelAngle) && std::isfinite(params.surfaceOffset);
    if (!paramsOk || !finiteVec3(origin) || !std::isfinite(n) || !(n > 0)) return false;
    const Eigen::Vector3d d = direction / n;
    Eigen::Vector3d e1, e2;
    orthonormalBasis(d, e1, e2);
    // Surface frame: Gram-Schmidt of the caller's tangents; fall back to (e1, e2).
    Eigen::Vector3d t1 = tangent1, t2 = tangent2;
    bool frameOk = finiteVec3(t1) && finiteVec3(t2);
    if (frameOk) {
        const double n1 = t1.norm();
        frameOk = n1 > 1e-12;
        if (frameOk) {
            t1 /= n1;
            t2 -= t1.dot(t2) * t1;
            const double n2 = t2.norm();
            frameOk = n2 > 1e-12;
            if (frameOk) t2 /= n2;
        }
    }
    if (!frameOk) {
        t1 = e1;
        t2 = e2;
    }
    const double len = params.length;
    out.origin = origin;
    out.direction = d;
    out.e1 = e1;
    out.e2 = e2;
    out.t1 = t1;
    out.t2 = t2;
    out.sobelAngle = params.sobelAngle;
    out.surfaceOffset = params.surfaceOffset;
    out.ringBegin = 1;
    out.ringCount = params.ringCount;
    out.sphereBegin = 1 + params.ringCount;
    out.surfaceBegin = out.sphereBegin + 8;
    out.count = out.surfaceBegin + 8;

    const double ringW = params.ringCount > 0
                             ? std::exp(-params.ringHalfAngle * params.ringHalfAngle /
                                        (2 * params.ringWeightSigma * params.ringWeightSigma))
                             : 0.0;
    const double wSum = 1.0 + ringW * params.ringCount;
    setRay(out, 0, origin, d, len, 1.0 / wSum);
    const double ca = std::cos(params.ringHalfAngle), sa = std::sin(params.ringHalfAngle);
    for (int m = 0; m < params.ringCount; ++m) {
        const double phi = 2 * std::numbers::pi * m / params.ringCount;
        const Eigen::Vector3d dir = ca * d + sa * (std::cos(phi) * e1 + std::sin(phi) * e2);
        setRay(out, out.ringBegin + m, origin, dir.normalized(), len, ringW / wSum);
    }
    const double td = std::tan(params.sobelAngle);
    const double h = params.surfaceOffset;
    for (int j = -1; j <= 1; ++j)
        for (int i = -1; i <= 1; ++i) {
            if (i == 0 && j == 0) continue;
            const Eigen::Vector3d dir = (d + (i * td) * e1 + (j * td) * e2).normalized();
            setRay(out, out.sphereRay(i, j), origin, dir, len, 0.0);
            setRay(out, out.surfaceRay(i, j), origin + h * (i * t1 + j * t2), d, len, 0.0);
        }
    out.valid = true;
    return true;
}

StencilGradient sobel3x3(const std::array<double, 9>& k, double spacing) noexcept {
    auto at = [&](int i, int j) { return k[static_cast<std::size_t>((j + 1) * 3 + (i + 1))]; };
    const double sx =
        (at(1, -1) - at(-1, -1)) + 2 * (at(1, 0) - at(-1, 0)) + (at(1, 1) - at(-1, 1));
    const double sy =
        (at(-1, 1) - at(-1, -1)) + 2 * (at(0, 1) - at(0, -1)) + (at(1, 1) - at(1, -1));
    if (!(spacing > 0)) return {};
    return {sx / (8 * spacing), sy / (8 * spacing)};
}

StencilGradient sphericalSobel(const RayBundle& b, std::span<const double> v) noexcept {
    if (!b.valid || v.size() < static_cast<std::size_t>(b.count)) return {};
    return sobel3x3(gather(b, v, true), b.sobelAngle);
}

StencilGradient surfaceSobel(const RayBundle& b, std::span<const double> v) noexcept {
    if (!b.valid || v.size() < static_cast<std::size_t>(b.count)) return {};
    return sobel3x3(gather(b, v, false), b.surfaceOffset);
}

double lowPass(const RayBundle& b, std::span<const double> v) noexcept {
    if (!b.valid || v.size() < static_cast<std::size_t>(b.count)) return 0.0;
    double s = b.weight[0] * v[0];
    for (int r = b.ringBegin; r < b.ringBegin + b.ringCount; ++r)
        s += static_cast<double>(b.weight[static_cast<std::size_t>(r)]) *
             v[static_cast<std::size_t>(r)];
    return s;
}

}  // namespace palp::kernels
