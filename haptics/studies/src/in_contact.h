#pragma once
// Internal to palp_haptics: the contact test shared by run summaries and maps.

#include "palp/haptics/session.h"

namespace palp::haptics::detail {

// Pressing on a surface: the proxy is held back from the probe (D above 1 um) or sits on a
// constraint. The distance also counts ticks in which the proxy changes constraint planes.
inline bool inContact(const Snapshot& s) { return s.contactCount > 0 || s.distance > 1e-6; }

}  // namespace palp::haptics::detail
