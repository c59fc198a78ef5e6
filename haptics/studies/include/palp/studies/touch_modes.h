#pragma once
/// @file
/// The touch modes of thesis paper III as paths the simulated hand runs over the stiffness
/// phantom (volume::PhantomScene::Stiffness: boxes DP, CP and CL side by side along x, the
/// surface at y = 0, depth +y):
///
/// * continuous pressure: one slow press along the normal into the CP box (harder below a
///   depth: paper III's stiffness that changes during one continuous contact; the scene's AVC
///   coupling renders it by the distance from the surface to that layer, which the press does
///   not change, so the hand feels one stiffness: docs/studies.md);
/// * discontinuous pressure: a press on the DP box (uniformly harder): in a two-interval study
///   each interval is one press on one object, lifted in between, so the two objects are
///   compared by touching them separately (paper III's "two objects");
/// * lateral sweep: back and forth across the CL box's soft-to-hard transition, pressed.
///
/// Paper III's stiffness JNDs of these modes (continuous pressure 5.23 %, discontinuous 12.91 %,
/// lateral sweep 15.77 %; docs/algorithms.md section 8) are the simulated observers' defaults.

#include <Eigen/Core>
#include <string_view>

#include "palp/haptics/devices/trajectory.h"

namespace palp::haptics {

enum class TouchMode { ContinuousPressure, DiscontinuousPressure, LateralSweep };

/// "continuous-pressure", "discontinuous-pressure", "lateral-sweep".
const char* touchModeName(TouchMode mode) noexcept;
/// The mode named by touchModeName() (also "cp", "dp", "cl" / "sweep").
/// @throw palp::ValueError naming @p what, the choices and @p name.
TouchMode parseTouchMode(std::string_view what, std::string_view name);
/// Whether @p name names a touch mode.
bool isTouchModeName(std::string_view name) noexcept;

/// Paper III's mean stiffness JND of @p mode as a fraction (0.0523, 0.1291, 0.1577).
double thesisWeberFraction(TouchMode mode) noexcept;

/// The stiffness box a study interval in @p mode touches (Phantom::stiffnessBoxCentreX index:
/// 0 DP, 1 CP, 2 CL).
int touchBox(TouchMode mode) noexcept;

/// A path over the stiffness phantom and what the runs need to know of it.
struct TouchPath {
    Trajectory trajectory;
    /// Time after which the path has done what it scripts, s.
    double seconds = 0;
    /// When the hand first rests pressed on the path (the felt figures start there), s.
    double pressedFrom = 0;
    /// The lateral axis a sweep runs along (profiles are felt along it).
    Eigen::Vector3d axis{Eigen::Vector3d::UnitX()};
};

/// What a touch path does; zero fields take touchDefaults().
struct TouchParams {
    double depthM = 0;    ///< below the surface
    double speedMps = 0;  ///< along the path (the press's mean speed)
    double holdSeconds = 0.2;
};
/// Depth 3 mm and 10 mm/s for the presses, 2 mm and 50 mm/s for the sweep.
TouchParams touchDefaults(TouchMode mode) noexcept;

/// The path of @p mode over one study interval's object (touchBox()): one press for the
/// pressure modes, two passes across the transition for the sweep.
/// @throw palp::ValueError naming the field for a depth outside (0, 20] mm or a speed outside
/// (0, 1] m/s.
TouchPath touchPath(TouchMode mode, const TouchParams& params = {});

}  // namespace palp::haptics
