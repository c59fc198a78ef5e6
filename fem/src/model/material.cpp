#include "palp/fem/material.h"

#include <cmath>

#include "palp/base/bounds.h"

namespace palp::fem {

double ElasticMaterial::lambda() const {
    return youngsModulus * poissonRatio / ((1.0 + poissonRatio) * (1.0 - 2.0 * poissonRatio));
}

double ElasticMaterial::mu() const { return youngsModulus / (2.0 * (1.0 + poissonRatio)); }

double ElasticMaterial::dilatationalWaveSpeed() const {
    return std::sqrt(youngsModulus * (1.0 - poissonRatio) /
                     (density * (1.0 + poissonRatio) * (1.0 - 2.0 * poissonRatio)));
}

void validate(const ElasticMaterial& m) {
    requireWithin("material youngsModulus", m.youngsModulus, bounds::kYoungsModulus);
    requireWithin("material poissonRatio", m.poissonRatio, bounds::kPoissonRatio);
    requireWithin("material density", m.density, bounds::kDensity);
    requireWithin("material dampingAlpha", m.dampingAlpha, bounds::kMassDamping);
    requireWithin("material dampingBeta", m.dampingBeta, bounds::kStiffnessDamping);
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
