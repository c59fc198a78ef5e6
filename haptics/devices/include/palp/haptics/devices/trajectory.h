#pragma once
/// @file
/// Scripted target paths for SimulatedDevice: press, lateral sweep with direction changes,
/// raster, circle, and sinusoidal strain inputs. Each gives position (m) and velocity (m/s) as
/// a function of time and is a plain value.
///
/// Conventions shared by every path:
/// * Time t is in seconds from the start of the path. For t < 0 the target rests where it is at
///   t = 0, with zero velocity.
/// * Positions are continuous in t and the velocity is the exact time derivative of the
///   position. The paths are C1 (velocity continuous) wherever a duration that smooths a
///   transition (approachSeconds, turnSeconds, rampSeconds, pressSeconds) is positive; a zero
///   duration gives the sharp version of that transition (a jump in velocity, or in position for
///   a zero approach). SinusoidTrajectory documents its own exceptions.
/// * Direction vectors need not be unit: sample() normalises them. A zero or non-finite vector
///   falls back to the member's default value (e.g. pressDirection (0, 1, 0), the phantoms'
///   depth axis). In-plane axes (u, v) are made orthonormal: v loses its component along u, and
///   when nothing is left v becomes the unit vector along pressDirection x u (or any unit vector
///   orthogonal to u when that too vanishes). pressDirection is not made orthogonal to (u, v).
/// * Lengths, speeds and durations that are negative or NaN count as zero. Frequencies keep their
///   sign (a negative frequency turns the other way); NaN counts as zero.
/// * Approach (sweep, raster, circle): over [0, approachSeconds] the target moves along
///   pressDirection from P - (depthM + approachM) pressDirection to P + depthM pressDirection,
///   where P is the path's first point on the surface, with the cosine profile
///   s(u) = (1 - cos(pi u)) / 2 (zero velocity at both ends). It then starts from rest on the
///   pressed path, so the path after the approach speeds up smoothly (see each type).
///
/// * Skin (every path): with a SkinField in @p skin, the flat path described here is laid on
///   the skin: each point moves along the field's press axis by the skin's height under it
///   (SkinField::apply), and the velocity gains the rate of that height along the path. The
///   path's own points (centre, start) are then on the field's plane, usually the plane of
///   SkinFieldSpec::centre; a flat skin on that plane (h = 0) leaves the path as it was.
///
/// @par Real-time
/// Every sample() and sampleTrajectory() is noexcept, allocation-free and O(1) (with a skin,
/// one bilinear lookup in its precomputed heights).

#include <Eigen/Core>
#include <memory>
#include <variant>

#include "palp/haptics/devices/skin_field.h"

namespace palp::haptics {

/// A press: the target starts at @p start, moves along @p direction (unit) by @p depthM over
/// @p pressSeconds, holds for @p holdSeconds, returns over @p pressSeconds and stays at start.
/// Motion along the path uses a smooth (cosine) velocity profile.
struct PressTrajectory {
    Eigen::Vector3d start{Eigen::Vector3d::Zero()};  ///< m
    Eigen::Vector3d direction{0.0, 0.0, -1.0};       ///< unit vector (normalised on use)
    double depthM = 0.01;                            ///< m
    double pressSeconds = 0.5;                       ///< s
    double holdSeconds = 0.5;                        ///< s

    /// The skin the path is laid on (see the file comment); nullptr: the flat path.
    std::shared_ptr<const SkinField> skin;
    /// Target position, m, and velocity, m/s, at time @p t (s).
    /// @par Real-time
    void sample(double t, Eigen::Vector3d& position, Eigen::Vector3d& velocity) const noexcept;
};

/// Back and forth along @p direction (unit, in the surface plane) over @p lengthM centred on
/// @p centre, at @p speedMps, reversing at each end (smooth cosine turn of @p turnSeconds);
/// the whole line is pressed @p depthM along @p pressDirection. Before the sweep the target
/// descends from @p centre - (depthM + approachM) pressDirection in approachSeconds.
///
/// After the approach (at centre + depthM pressDirection, at rest) the lateral offset x(t)
/// along direction is:
/// * speed-up over turnSeconds / 2 (same peak acceleration as a turn): the speed rises as
///   speedMps (1 - cos(pi tau / (turnSeconds / 2))) / 2, moving toward +direction;
/// * then a periodic pattern: straight at +-speedMps, and turns in which the velocity is
///   speedMps cos(pi tau / turnSeconds) (reversed at the negative end). A turn's extreme point
///   is exactly +-lengthM / 2 (the turn starts speedMps turnSeconds / pi before the end).
///   Period 2 (lengthM - 2 speedMps turnSeconds / pi) / speedMps + 2 turnSeconds.
/// * turnSeconds is reduced to lengthM / (speedMps (1/2 + 2/pi)) when larger, so that the
///   speed-up ends before the first turn begins.
/// The depth is held along the whole sweep. With lengthM or speedMps zero the target stays at
/// centre + depthM pressDirection after the approach. The sweep never ends.
struct SweepTrajectory {
    Eigen::Vector3d centre{Eigen::Vector3d::Zero()};  ///< on the surface, m
    Eigen::Vector3d direction{1.0, 0.0, 0.0};         ///< sweep axis, unit
    Eigen::Vector3d pressDirection{0.0, 1.0, 0.0};    ///< into the surface, unit
    double lengthM = 0.04;
    double speedMps = 0.05;
    double depthM = 0.004;
    double approachM = 0.005;
    double approachSeconds = 0.3;
    double turnSeconds = 0.1;
    /// The skin the path is laid on (see the file comment); nullptr: the flat path.
    std::shared_ptr<const SkinField> skin;
    /// turnSeconds after the clamp above, s.
    double effectiveTurnSeconds() const noexcept;
    /// Time of one back-and-forth cycle after the speed-up, s (0 when the sweep does not move).
    double periodSeconds() const noexcept;
    void sample(double t, Eigen::Vector3d& position, Eigen::Vector3d& velocity) const noexcept;
};

/// Boustrophedon raster over a rectangle (@p extentU along @p u, @p extentV along @p v, centred
/// on @p centre), lines @p lineSpacingM apart, at @p speedMps, pressed @p depthM along
/// @p pressDirection. Ends (and stays) at the last line's end. durationSeconds() says when.
///
/// Geometry (in the (u, v) plane, offsets from centre):
/// * lineCount() = floor(extentV / lineSpacingM) + 1 lines (1 when the spacing or extentV is
///   zero), at v_i = (i - (lineCount() - 1) / 2) lineSpacingM, i.e. centred on centre, each
///   spanning the full u range [-extentU / 2, extentU / 2]. Line 0 runs toward +u, line 1 toward
///   -u, and so on.
/// * Consecutive lines are joined by half circles of diameter lineSpacingM, travelled at the
///   same speed, which bulge lineSpacingM / 2 beyond the rectangle in u (the tangent is
///   continuous, so the path is C1).
/// * Start: (-extentU / 2, v_0). End: (+extentU / 2, v_last) for an odd line count,
///   (-extentU / 2, v_last) for an even one. See startOffset() and endOffset().
/// Timing: the approach (onto the start), then the path's arc length pathLengthM() at
/// speedMps, with a cosine speed-up over rampSeconds at the start and a matching slow-down at
/// the end (each costs rampSeconds / 2 over constant speed; rampSeconds is reduced to
/// pathLengthM() / speedMps when larger). So durationSeconds() = approachSeconds + rampSeconds +
/// pathLengthM() / speedMps exactly. With speedMps zero the target stays at the start.
struct RasterTrajectory {
    Eigen::Vector3d centre{Eigen::Vector3d::Zero()};
    Eigen::Vector3d u{1.0, 0.0, 0.0}, v{0.0, 0.0, 1.0};
    Eigen::Vector3d pressDirection{0.0, 1.0, 0.0};
    double extentU = 0.06, extentV = 0.06;
    double lineSpacingM = 0.002;
    double speedMps = 0.1;
    double depthM = 0.004;
    double approachM = 0.005;
    double approachSeconds = 0.3;
    double rampSeconds = 0.05;  ///< speed-up and slow-down time, s (addition to issue 4's draft)
    /// The skin the path is laid on (see the file comment); nullptr: the flat path.
    std::shared_ptr<const SkinField> skin;
    double durationSeconds() const noexcept;
    /// Number of lines (see above); at most 10^7.
    long long lineCount() const noexcept;
    /// Arc length of the pressed path, lines and half circles, m.
    double pathLengthM() const noexcept;
    /// First and last point of the path on the surface as (u, v) offsets from centre, m.
    Eigen::Vector2d startOffset() const noexcept;
    Eigen::Vector2d endOffset() const noexcept;
    void sample(double t, Eigen::Vector3d& position, Eigen::Vector3d& velocity) const noexcept;
};

/// Circle of @p radiusM in the plane (u, v) around @p centre at @p frequencyHz, pressed
/// @p depthM along @p pressDirection (after an approach as above).
///
/// The approach comes down onto the circle's start point centre + radiusM u. The angle from u
/// (toward v for a positive frequency) then speeds up from rest over rampSeconds (angular
/// velocity 2 pi f (1 - cos(pi tau / rampSeconds)) / 2) and afterwards turns at exactly
/// 2 pi frequencyHz rad/s, for ever.
struct CircleTrajectory {
    Eigen::Vector3d centre{Eigen::Vector3d::Zero()};
    Eigen::Vector3d u{1.0, 0.0, 0.0}, v{0.0, 0.0, 1.0};
    Eigen::Vector3d pressDirection{0.0, 1.0, 0.0};
    double radiusM = 0.01;
    double frequencyHz = 1;
    double depthM = 0.004;
    double approachM = 0.005;
    double approachSeconds = 0.3;
    double rampSeconds = 0.25;  ///< spin-up time, s (addition to issue 4's draft)
    /// The skin the path is laid on (see the file comment); nullptr: the flat path.
    std::shared_ptr<const SkinField> skin;
    void sample(double t, Eigen::Vector3d& position, Eigen::Vector3d& velocity) const noexcept;
};

/// The thesis's strain inputs: position start + a(t) sin(2 pi f t) direction, with a(t) =
/// amplitudeM, or growing linearly from 0 to amplitudeM over growSeconds when growSeconds > 0.
///
/// There is no approach: the input starts at t = 0 at @p start. The envelope is the documented
/// linear one, so the path is C1 except (a) at t = 0 when growSeconds is 0 (the velocity steps
/// from 0 to 2 pi f amplitudeM) and (b) at t = growSeconds, where the velocity steps by
/// -(amplitudeM / growSeconds) sin(2 pi f growSeconds); choose growSeconds as a whole number
/// of half periods to make that step zero. At those instants sample() returns the velocity
/// just after.
struct SinusoidTrajectory {
    Eigen::Vector3d start{Eigen::Vector3d::Zero()};
    Eigen::Vector3d direction{0.0, 1.0, 0.0};
    double amplitudeM = 0.002;
    double frequencyHz = 1;
    double growSeconds = 0;
    /// The skin the path is laid on (see the file comment); nullptr: the flat path.
    std::shared_ptr<const SkinField> skin;
    void sample(double t, Eigen::Vector3d& position, Eigen::Vector3d& velocity) const noexcept;
};

/// Any of the scripted paths.
using Trajectory = std::variant<PressTrajectory, SweepTrajectory, RasterTrajectory,
                                CircleTrajectory, SinusoidTrajectory>;

/// Set-up check of a path against palp/base/bounds.h: points within bounds::kPosition, direction
/// vectors finite, lengths, depths, radii and amplitudes within bounds::kSpan, speeds within
/// bounds::kSpeed, durations within bounds::kDuration (the press within kPositiveDuration),
/// |frequency| within bounds::kFrequency. sample() itself stays lenient as documented above;
/// this refuses what no caller means (NaN, 1e300 m) before a session is built on it.
/// @throw palp::ValueError naming the type and the member, e.g. `CircleTrajectory radiusM`.
void validateTrajectory(const Trajectory& trajectory);

/// Position and velocity of @p trajectory at time @p t (s).
/// @par Real-time  noexcept, no allocation.
void sampleTrajectory(const Trajectory& trajectory, double t, Eigen::Vector3d& position,
                      Eigen::Vector3d& velocity) noexcept;

}  // namespace palp::haptics
