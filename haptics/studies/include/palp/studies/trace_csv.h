#pragma once
/// @file
/// Writing a run's snapshots as a CSV trace.

#include <filesystem>
#include <span>

#include "palp/haptics/session.h"

namespace palp::haptics {

/// Writes a CSV trace, one row per snapshot, SI units:
/// `t,tick,probe_x,probe_y,probe_z,proxy_x,proxy_y,proxy_z,force_x,force_y,force_z,stiffness,
/// ray_length,distance,energy_force_x,energy_force_y,energy_force_z,proxy_force_x,
/// proxy_force_y,proxy_force_z,coupling_energy,observer_energy,added_damping,contacts,rays,
/// sticking,gate_open,faulted,clamped`. Temporary file renamed into place.
/// @throw palp::IoError naming the file.
void writeTraceCsv(const std::filesystem::path& path, std::span<const Snapshot> snapshots);

}  // namespace palp::haptics
