#include "palp/fem/coupling_spring.h"

#include <algorithm>
#include <cmath>

namespace palp::fem {

bool CouplingSpring::active() const noexcept {
    return stiffness > 0.0 && std::isfinite(stiffness) && !nodes.empty() &&
           weights.size() >= nodes.size();
}

Eigen::Vector3d springForce(const CouplingSpring& spring, const Eigen::Vector3d& a) noexcept {
    Eigen::Vector3d f = spring.stiffness * (spring.target - a);
    const double n = f.norm();
    if (!std::isfinite(n)) return Eigen::Vector3d::Zero();
    if (n > spring.maxForce) f *= spring.maxForce / n;
    return f;
}

double springFrequencySquared(const FemModel& model, const CouplingSpring& spring) noexcept {
    if (!spring.active()) return 0.0;
    const Eigen::VectorXd& mass = model.lumpedMass();
    double sum = 0.0;
    for (std::size_t i = 0; i < spring.nodes.size(); ++i) {
        const double w = spring.weights[i];
        if (w == 0.0) continue;
        const double m = mass[3 * static_cast<Eigen::Index>(spring.nodes[i])];
        if (!(m > 0.0)) return std::numeric_limits<double>::infinity();
        sum += w * w / m;
    }
    return spring.stiffness * sum;
}

double criticalDamping(const FemModel& model, const CouplingSpring& spring, double ratio) noexcept {
    if (!spring.active() || !(ratio > 0.0)) return 0.0;
    const double w2 = springFrequencySquared(model, spring);  // k / m_eff
    if (!(w2 > 0.0) || !std::isfinite(w2)) return 0.0;
    // 2 sqrt(k m_eff) = 2 k / sqrt(k / m_eff).
    return ratio * 2.0 * spring.stiffness / std::sqrt(w2);
}

double criticalTimeStepWith(const FemModel& model, double extraOmega2) noexcept {
    const double w0 = model.maxFrequencyBound();
    const double w = std::sqrt(w0 * w0 + std::max(0.0, extraOmega2));
    const ElasticMaterial& m = model.material();
    const double xi = 0.5 * (m.dampingAlpha / w + m.dampingBeta * w);
    return 2.0 / (w * (std::sqrt(1.0 + xi * xi) + xi));
}

}  // namespace palp::fem
