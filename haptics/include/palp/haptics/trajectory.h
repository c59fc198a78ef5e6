#pragma once
/// @file
/// Scripted target paths for SimulatedDevice: press, lateral sweep with direction changes,
/// raster, circle, and sinusoidal strain inputs. Each gives position (m) and velocity (m/s) as
/// a function of time and is a plain value.

#include <Eigen/Core>
#include <variant>

#include "palp/haptics/simulated_device.h"  // PressTrajectory

namespace palp::haptics {

/// Back and forth along @p direction (unit, in the surface plane) over @p lengthM centred on
/// @p centre, at @p speedMps, reversing at each end (smooth cosine turn of @p turnSeconds);
/// the whole line is pressed @p depthM along @p pressDirection. Before the sweep the target
/// descends from @p centre - (depthM + approachM) pressDirection in approachSeconds.
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
    void sample(double t, Eigen::Vector3d& position, Eigen::Vector3d& velocity) const noexcept;
};

/// Boustrophedon raster over a rectangle (@p extentU along @p u, @p extentV along @p v, centred
/// on @p centre), lines @p lineSpacingM apart, at @p speedMps, pressed @p depthM along
/// @p pressDirection. Ends (and stays) at the last line's end. durationSeconds() says when.
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
    double durationSeconds() const noexcept;
    void sample(double t, Eigen::Vector3d& position, Eigen::Vector3d& velocity) const noexcept;
};

/// Circle of @p radiusM in the plane (u, v) around @p centre at @p frequencyHz, pressed
/// @p depthM along @p pressDirection (after an approach as above).
struct CircleTrajectory {
    Eigen::Vector3d centre{Eigen::Vector3d::Zero()};
    Eigen::Vector3d u{1.0, 0.0, 0.0}, v{0.0, 0.0, 1.0};
    Eigen::Vector3d pressDirection{0.0, 1.0, 0.0};
    double radiusM = 0.01;
    double frequencyHz = 1;
    double depthM = 0.004;
    double approachM = 0.005;
    double approachSeconds = 0.3;
    void sample(double t, Eigen::Vector3d& position, Eigen::Vector3d& velocity) const noexcept;
};

/// The thesis's strain inputs: position start + a(t) sin(2 pi f t) direction, with a(t) =
/// amplitudeM, or growing linearly from 0 to amplitudeM over growSeconds when growSeconds > 0.
struct SinusoidTrajectory {
    Eigen::Vector3d start{Eigen::Vector3d::Zero()};
    Eigen::Vector3d direction{0.0, 1.0, 0.0};
    double amplitudeM = 0.002;
    double frequencyHz = 1;
    double growSeconds = 0;
    void sample(double t, Eigen::Vector3d& position, Eigen::Vector3d& velocity) const noexcept;
};

/// Any of the scripted paths.
using Trajectory = std::variant<PressTrajectory, SweepTrajectory, RasterTrajectory,
                                CircleTrajectory, SinusoidTrajectory>;

/// Position and velocity of @p trajectory at time @p t (s).
/// @par Real-time  noexcept, no allocation.
void sampleTrajectory(const Trajectory& trajectory, double t, Eigen::Vector3d& position,
                      Eigen::Vector3d& velocity) noexcept;

}  // namespace palp::haptics
