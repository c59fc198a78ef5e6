#pragma once
/// @file
/// The whole loop's energy budget, tick by tick (docs/algorithms.md section 3): where the energy
/// the rendered force puts into the hand comes from.
///
/// Between ticks n and n+1 (forces F, positions x, stored coupling energy E = 1/2 k D^2 as the
/// snapshots report them; trapezoidal rule for the coupling's own work):
///
/// * hand work            W_hand  = F_sent(n) . (x_pb(n+1) - x_pb(n)): the work the force the
///                        device holds over the period does on the hand (zero-order hold);
/// * probe-port work      W_pb    = 1/2 (F_c(n) + F_c(n+1)) . dx_pb, F_c the coupling's force on
///                        the probe before guard, clamp, gate and controller;
/// * proxy work           W_py    = 1/2 (P(n) + P(n+1)) . dx_py with P = -F_c + F_py the
///                        coupling's force on the proxy (the spring's reaction and AVCEC's
///                        surface term): what the proxy's motion took out of the coupling
///                        (friction dissipates it; a frictionless proxy at equilibrium has
///                        P_t = 0);
/// * stored change        dE      = E(n+1) - E(n);
/// * created              C       = dE + W_pb + W_py: energy the coupling gave away beyond
///                        what it stored (zero for a conservative coupling; AVC's
///                        direction-dependent k makes it non-zero);
/// * rendering            R       = W_hand - W_pb: what the zero-order hold, clamping, the
///                        start-up gate and the passivity controller added.
///
/// So W_hand = C - dE - W_py + R holds tick by tick by construction, and over a closed path
/// (dE = 0) the energy the hand received is what the coupling created, minus what the proxy's
/// motion (friction) dissipated, plus what rendering added. Sums are kept in double.
///
/// Deformable scenes: the proxy is carried with the deformed surface, so W_py also holds the
/// work exchanged with the tissue (which stores and dissipates it), and C is then not the
/// coupling's creation alone (it read +1 mJ on deformable closed loops whose hand work was
/// negative, test_deformable_study). Judge deformable runs by W_hand over closed paths.
///
/// @par Threading  A plain accumulator; one thread.
/// @par Real-time  add() is noexcept, allocation-free and O(1).

#include <cstdint>
#include <span>

#include "palp/haptics/session.h"

namespace palp::haptics {

struct EnergyBudget {
    double handWork = 0;      ///< sum of W_hand, J (positive: energy into the hand)
    double probeWork = 0;     ///< sum of W_pb, J
    double proxyWork = 0;     ///< sum of W_py, J
    double storedChange = 0;  ///< sum of dE, J
    double created = 0;       ///< sum of C, J
    double rendering = 0;     ///< sum of R, J
    double proxyPath = 0;     ///< distance the proxy travelled, m
    double probePath = 0;     ///< distance the probe travelled, m
    std::uint64_t intervals = 0;

    /// Books the interval from @p before to @p after (consecutive ticks of one session).
    /// Non-finite values in either snapshot skip the interval.
    void add(const Snapshot& before, const Snapshot& after) noexcept;
};

/// The budget over consecutive @p snapshots from time @p fromSeconds on.
EnergyBudget energyBudget(std::span<const Snapshot> snapshots, double fromSeconds = 0) noexcept;

}  // namespace palp::haptics
