#include "palp/fem/material.h"

#include <cmath>
#include <sstream>

#include "palp/base/error.h"

namespace palp::fem {

double ElasticMaterial::lambda() const {
    return youngsModulus * poissonRatio / ((1.0 + poissonRatio) * (1.0 - 2.0 * poissonRatio));
}

double ElasticMaterial::mu() const { return youngsModulus / (2.0 * (1.0 + poissonRatio)); }

double ElasticMaterial::dilatationalWaveSpeed() const {
    return std::sqrt(youngsModulus * (1.0 - poissonRatio) /
                     (density * (1.0 + poissonRatio) * (1.0 - 2.0 * poissonRatio)));
}

namespace {
[[noreturn]] void fail(const char* item, const char* expected, double found) {
    std::ostringstream s;
    s << "material " << item << ": expected " << expected << ", found " << found;
    throw ValueError(s.str());
}
}  // namespace

void validate(const ElasticMaterial& m) {
    if (!std::isfinite(m.youngsModulus) || m.youngsModulus <= 0.0) {
        fail("Young's modulus", "a finite value > 0 Pa", m.youngsModulus);
    }
    if (!std::isfinite(m.poissonRatio) || m.poissonRatio <= -1.0 || m.poissonRatio >= 0.5) {
        fail("Poisson's ratio", "a value in (-1, 0.5)", m.poissonRatio);
    }
    if (!std::isfinite(m.density) || m.density <= 0.0) {
        fail("density", "a finite value > 0 kg/m^3", m.density);
    }
    if (!std::isfinite(m.dampingAlpha) || m.dampingAlpha < 0.0) {
        fail("damping alpha", "a finite value >= 0 1/s", m.dampingAlpha);
    }
    if (!std::isfinite(m.dampingBeta) || m.dampingBeta < 0.0) {
        fail("damping beta", "a finite value >= 0 s", m.dampingBeta);
    }
}

Eigen::Matrix<double, 6, 6> elasticityMatrix(double e, double nu) {
    const double lam = e * nu / ((1.0 + nu) * (1.0 - 2.0 * nu));
    const double mu = e / (2.0 * (1.0 + nu));
    Eigen::Matrix<double, 6, 6> c = Eigen::Matrix<double, 6, 6>::Zero();
    for (int i = 0; i < 3; ++i) {
        for (int j = 0; j < 3; ++j) c(i, j) = lam;
        c(i, i) = lam + 2.0 * mu;
        c(i + 3, i + 3) = mu;
    }
    return c;
}

}  // namespace palp::fem
