#pragma once
/// @file
/// The physically meaningful range of every quantity palp accepts, stated once (in SI units) and
/// used by the library's set-up checks, the C API and the command line. A finite but absurd value
/// (a 1e300 m path, a 1e300 Pa tissue) is refused here, before it reaches Embree, OpenVDB or a
/// solver loop, with the same `<what>: expected ..., found ...` message as validate.h.
///
/// The ranges are generous (anything a scan, a haptic device or soft tissue can need, with an
/// order of magnitude to spare) and bounded (every product palp forms from them stays finite and
/// every loop they drive stays bounded). Not for the servo path: the checks throw.

#include <string>
#include <string_view>

namespace palp {

/// The accepted range of one quantity, in SI units. Ends are closed unless marked open.
struct Bounds {
    double min;
    double max;
    std::string_view unit;  ///< SI unit as printed ("m", "N/m"; empty: dimensionless)
    bool minOpen = false;   ///< (min, ...] instead of [min, ...]
    bool maxOpen = false;   ///< [..., max) instead of [..., max]

    /// True when @p v is finite and inside.
    constexpr bool contains(double v) const noexcept {
        return v == v && (minOpen ? v > min : v >= min) && (maxOpen ? v < max : v <= max);
    }
};

/// How a caller shows a quantity to its user: the value in SI units times @p scale, in @p unit
/// (the command line speaks mm and kPa: {1e3, "mm"}, {1e-3, "kPa"}).
struct DisplayUnit {
    double scale = 1;
    std::string_view unit;
};

namespace bounds {

// Lengths, m.
/// A point in the world or on a device: scanners and workspaces are metres across.
inline constexpr Bounds kPosition{-10, 10, "m"};
/// A length that must be positive: a path, an extent, a ray, a reference length.
inline constexpr Bounds kLength{0, 10, "m", true};
/// A length that may be zero: a depth, an approach, a radius, an amplitude, a span.
inline constexpr Bounds kSpan{0, 10, "m"};
/// A fine spacing: a voxel edge, a ray step, an FEM cell, a stencil offset, a line spacing, a
/// map pixel (1 um to 10 cm).
inline constexpr Bounds kSpacing{1e-6, 0.1, "m"};

// Time and rate.
/// A duration: a run, a hold, a ramp (up to an hour of simulated or real time).
inline constexpr Bounds kDuration{0, 3600, "s"};
/// A duration that must be positive (a press, an approach, a turn, a fade).
inline constexpr Bounds kPositiveDuration{0, 3600, "s", true};
/// A short window after an event (a re-contact's force limit): up to a second.
inline constexpr Bounds kWindow{0, 1, "s"};
/// A servo period: 10 us (100 kHz) to 0.1 s (10 Hz).
inline constexpr Bounds kPeriod{1e-5, 0.1, "s"};
/// A part of a servo period (a spin before the deadline, a simulated workload): up to 0.1 s.
inline constexpr Bounds kPeriodPart{0, 0.1, "s"};
/// A frequency of motion or of a solver: up to 1 kHz.
inline constexpr Bounds kFrequency{0, 1000, "Hz"};
/// The rate of a solver or of a lower-rate loop (at least 1 Hz, at most the servo's 1 kHz).
inline constexpr Bounds kSolverRate{1, 1000, "Hz"};
/// A frequency that must be positive (a circle's revolutions per second).
inline constexpr Bounds kPositiveFrequency{0, 1000, "Hz", true};
/// A speed along a path (0: the path stands still).
inline constexpr Bounds kSpeed{0, 10, "m/s"};
/// A speed that must be positive.
inline constexpr Bounds kPositiveSpeed{0, 10, "m/s", true};

// Mechanics.
/// A stiffness of a coupling, a surface or a hand (devices render ~1e3-1e4 N/m).
inline constexpr Bounds kStiffness{0, 1e6, "N/m"};
/// A stiffness that must be positive (a coupling's k_s, its clamp k_max).
inline constexpr Bounds kPositiveStiffness{0, 1e6, "N/m", true};
/// A viscous damping coefficient.
inline constexpr Bounds kDamping{0, 1e4, "N s/m"};
/// A force (devices render a few N to tens of N).
inline constexpr Bounds kForce{0, 1000, "N"};
/// A force that must be positive (a threshold, a limit).
inline constexpr Bounds kPositiveForce{0, 1000, "N", true};
/// A rate of change of a force that must be positive (a limit on its rise).
inline constexpr Bounds kForceRate{0, 1e6, "N/s", true};
/// A mass (a hand, a tool): from a gram.
inline constexpr Bounds kMass{1e-3, 1000, "kg"};
/// Young's modulus: from the softest gel (1 Pa) to steel and beyond (1 TPa).
inline constexpr Bounds kYoungsModulus{1, 1e12, "Pa"};
/// Poisson's ratio of an isotropic solid.
inline constexpr Bounds kPoissonRatio{-1, 0.5, "", true, true};
/// A density.
inline constexpr Bounds kDensity{1, 1e5, "kg/m^3"};
/// Mass-proportional (Rayleigh alpha) damping.
inline constexpr Bounds kMassDamping{0, 1e4, "1/s"};
/// Stiffness-proportional (Rayleigh beta) damping.
inline constexpr Bounds kStiffnessDamping{0, 1, "s"};
/// A friction coefficient.
inline constexpr Bounds kFriction{0, 10, ""};

// Rays and volumes.
/// A stencil or cone angle (Sobel spacing, ring half-angle).
inline constexpr Bounds kAngle{0, 1.5707963267948966, "rad", true};
/// AVCEC's largest ray tilt theta_c from the contact normal (pi/2: no limit).
inline constexpr Bounds kRayTilt{0.01, 1.5707963267948966, "rad"};
/// A tilt from an axis (a gantry tilt, a slab's slope): within 80 degrees either way.
inline constexpr Bounds kTiltAngle{-1.3962634015954636, 1.3962634015954636, "rad"};
/// A stiffness multiplier m_max.
inline constexpr Bounds kMultiplier{1, 1000, ""};
/// A value of a volume (HU, MR units, a threshold, an iso-value): inside float range with room.
inline constexpr Bounds kVolumeValue{-1e9, 1e9, ""};
/// A spread of volume values (a noise standard deviation).
inline constexpr Bounds kVolumeSpread{0, 1e6, ""};
/// A hardness (accumulate's sigma), 1/m.
inline constexpr Bounds kHardness{0, 1e9, "1/m"};
/// A hardness that must be positive.
inline constexpr Bounds kPositiveHardness{0, 1e9, "1/m", true};
/// The accumulated-hardness integral at which a ray stops.
inline constexpr Bounds kTauStop{0, 1000, "", true};
/// A dimensionless shape factor of a profile (a tanh's sharpness).
inline constexpr Bounds kShapeFactor{0, 1000, "", true};
/// Metres per unit of a mesh file (1e-3 for millimetres).
inline constexpr Bounds kMeshUnit{1e-6, 1000, "m"};
/// A workspace scale (world metres per device metre).
inline constexpr Bounds kScale{0, 1000, "", true};

}  // namespace bounds

/// Throws palp::ValueError (`<what>: expected a value in [min, max] <unit>, found <v>`) unless
/// @p v (SI units) is finite and inside @p b.
void requireWithin(std::string_view what, double v, const Bounds& b);
/// The same, showing the range and the value in the caller's @p display unit (empty: SI).
void requireWithin(std::string_view what, double v, const Bounds& b, DisplayUnit display);
/// The range as the message shows it, e.g. `a value in (0, 10000] mm`.
std::string describe(const Bounds& b, DisplayUnit display = {});

}  // namespace palp
