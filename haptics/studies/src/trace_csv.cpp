#include "palp/studies/trace_csv.h"

#include <algorithm>
#include <cstdio>
#include <string>

#include "palp/base/atomic_file.h"

namespace palp::haptics {

void writeTraceCsv(const std::filesystem::path& path, std::span<const Snapshot> snapshots) {
    std::string text =
        "t,tick,probe_x,probe_y,probe_z,proxy_x,proxy_y,proxy_z,force_x,force_y,force_z,"
        "stiffness,ray_length,distance,energy_force_x,energy_force_y,energy_force_z,"
        "proxy_force_x,proxy_force_y,proxy_force_z,coupling_energy,observer_energy,"
        "added_damping,contacts,rays,sticking,gate_open,faulted,clamped\n";
    text.reserve(text.size() + snapshots.size() * 360);
    char line[1024];
    for (const Snapshot& s : snapshots) {
        const int n = std::snprintf(
            line, sizeof line,
            "%.6f,%llu,%.9g,%.9g,%.9g,%.9g,%.9g,%.9g,%.6g,%.6g,%.6g,%.6g,%.9g,%.9g,%.6g,%.6g,%.6g,"
            "%.6g,%.6g,%.6g,%.6g,%.6g,%.6g,%d,%d,%d,%d,%d,%d\n",
            s.timeSeconds, static_cast<unsigned long long>(s.tick), s.probe.x(), s.probe.y(),
            s.probe.z(), s.proxy.x(), s.proxy.y(), s.proxy.z(), s.force.x(), s.force.y(),
            s.force.z(), s.stiffness, s.rayLength, s.distance, s.energyForce.x(), s.energyForce.y(),
            s.energyForce.z(), s.proxyForce.x(), s.proxyForce.y(), s.proxyForce.z(),
            s.couplingEnergy, s.observerEnergy, s.addedDamping, s.contactCount, s.rays,
            s.sticking ? 1 : 0, s.gateOpen ? 1 : 0, s.faulted ? 1 : 0, s.clamped ? 1 : 0);
        if (n > 0) text.append(line, std::min(static_cast<std::size_t>(n), sizeof line - 1));
    }
    palp::writeFileAtomically(path, "trace CSV", text.data(), text.size());
}

}  // namespace palp::haptics
