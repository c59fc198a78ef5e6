#include "palp/studies/energy_budget.h"

#include <cmath>

namespace palp::haptics {

void EnergyBudget::add(const Snapshot& a, const Snapshot& b) noexcept {
    const Eigen::Vector3d dpb = b.probe - a.probe;
    const Eigen::Vector3d dpy = b.proxy - a.proxy;
    const double hand = a.force.dot(dpb);
    const double probe = 0.5 * (a.couplingForce + b.couplingForce).dot(dpb);
    const Eigen::Vector3d pa = -a.couplingForce + a.proxyForce;
    const Eigen::Vector3d pb = -b.couplingForce + b.proxyForce;
    const double proxy = 0.5 * (pa + pb).dot(dpy);
    const double stored = b.couplingEnergy - a.couplingEnergy;
    if (!std::isfinite(hand) || !std::isfinite(probe) || !std::isfinite(proxy) ||
        !std::isfinite(stored))
        return;
    handWork += hand;
    probeWork += probe;
    proxyWork += proxy;
    storedChange += stored;
    created += stored + probe + proxy;
    rendering += hand - probe;
    proxyPath += dpy.norm();
    probePath += dpb.norm();
    ++intervals;
}

EnergyBudget energyBudget(std::span<const Snapshot> snapshots, double fromSeconds) noexcept {
    EnergyBudget budget;
    for (std::size_t i = 1; i < snapshots.size(); ++i)
        if (snapshots[i - 1].timeSeconds >= fromSeconds) budget.add(snapshots[i - 1], snapshots[i]);
    return budget;
}

}  // namespace palp::haptics
