#pragma once
/// @file
/// AsyncSetup: the validated options and the fixed data of AsyncRegions that every part reads
/// (primary region, secondary region, layout builder), and the secondary's time-scheme
/// coefficients.

#include <array>
#include <cstdint>
#include <memory>
#include <vector>

#include "palp/fem/async_regions.h"

namespace palp::fem {

/// Newmark / backward Euler coefficients of the secondary's period (zero for quasi-static).
struct NewmarkCoefficients {
    double a0 = 0, a1 = 0, a2 = 0, a3 = 0, a4 = 0, a5 = 0;
};

/// The coefficients of @p integrator for a step of @p dt seconds.
NewmarkCoefficients newmarkCoefficients(Integrator integrator, double dt);

/// Validated options and per-node / per-dof data fixed for the object's life.
/// @par Threading  Written once by the constructor (on the constructing thread, before any other
/// thread starts); read-only afterwards, so every thread reads it without synchronisation.
struct AsyncSetup {
    /// Validates @p options against @p model, @p constraints and @p contactNodes.
    /// @throw palp::ValueError as AsyncRegions's constructor documents.
    AsyncSetup(const FemModel& model, const Constraints& constraints,
               const std::vector<int>& contactNodes, const AsyncRegionsOptions& options);

    /// Fraction of a secondary period elapsed at @p time since the coupling clock @p start,
    /// clamped to [0, 1]; 1 when interpolation is off. @par Real-time  noexcept.
    double periodFraction(double time, double start) const noexcept;

    const FemModel& model;
    AsyncRegionsOptions options;
    bool forceDrive = false;
    bool adaptive = false;                        // maxPrimaryNodes > primaryNodes
    std::vector<int> watchIndex;                  // per fine node: index in watchNodes, or -1
    std::vector<std::uint8_t> fixed;              // per fine dof: constrained by the caller
    std::vector<int> watchFixedDofs;              // 3 * watch index + k of fixed watched dofs
    std::vector<std::uint8_t> watchPlain;         // per watched node: active, no fixed dof (1)
    std::vector<std::uint8_t> nonZeroPrescribed;  // per fine node
    int lod = 1;
    std::array<int, 3> coarseCounts{};  // coarse nodes per axis
    int coarseDofs = 0;
    int period = 1;              // ticks per secondary period
    double periodSeconds = 0.0;  // secondary period, s
    NewmarkCoefficients nm;      // secondary time scheme over one period
    double sK = 1.0, sM = 0.0;   // secondary system: sK K + sM M
    // A neo-Hookean model's primary element (the secondary stays linear); null for linear.
    std::shared_ptr<const TledForces> tled;
};

}  // namespace palp::fem
