#pragma once
/// @file
/// A simulated device: a hand model (mass-spring-damper) follows a scripted target path, and
/// the rendered force acts on it, so the force feeds back into the motion.

#include <Eigen/Core>

#include "palp/haptics/device.h"

namespace palp::haptics {

/// A press: the target starts at @p start, moves along @p direction (unit) by @p depthM over
/// @p pressSeconds, holds for @p holdSeconds, returns over @p pressSeconds and stays at start.
/// Motion along the path uses a smooth (cosine) velocity profile.
struct PressTrajectory {
    Eigen::Vector3d start{Eigen::Vector3d::Zero()};  ///< m
    Eigen::Vector3d direction{0.0, 0.0, -1.0};       ///< unit vector
    double depthM = 0.01;                            ///< m
    double pressSeconds = 0.5;                       ///< s
    double holdSeconds = 0.5;                        ///< s

    /// Target position, m, and velocity, m/s, at time @p t (s).
    /// @par Real-time
    void sample(double t, Eigen::Vector3d& position, Eigen::Vector3d& velocity) const noexcept;
};

/// Hand model parameters: the hand is a point mass pulled toward the target by a spring and a
/// damper (the user's arm and grip), and pushed by the device force.
struct HandModel {
    double massKg = 0.1;          ///< kg
    double stiffnessNpm = 300.0;  ///< N/m
    double dampingNspm = 6.0;     ///< N s/m
};

/// A Device driven by a PressTrajectory and a HandModel, stepped at a fixed period.
///
/// @par Threading
/// Like any Device: read() and write() from the servo thread only.
/// @par Real-time
/// read() and write() are noexcept, allocation-free and O(1).
class SimulatedDevice final : public Device {
  public:
    /// @param spec limits reported by spec() (write() clamps the force to spec.maxForceN)
    /// @param periodSeconds simulation step per read(), s
    SimulatedDevice(const DeviceSpec& spec, const PressTrajectory& trajectory,
                    const HandModel& hand, double periodSeconds) noexcept;

    /// Advances the hand model by one period under the last written force and returns it.
    DeviceState read() noexcept override;
    /// Sets the force on the hand, N, clamped to the spec's maximum.
    void write(const Eigen::Vector3d& forceN) noexcept override;
    const DeviceSpec& spec() const noexcept override { return mSpec; }

    /// The force applied in the next step, N (after clamping).
    const Eigen::Vector3d& appliedForce() const noexcept { return mForce; }

  private:
    DeviceSpec mSpec;
    PressTrajectory mTrajectory;
    HandModel mHand;
    double mPeriod;
    long long mTick = 0;
    DeviceState mState;
    Eigen::Vector3d mForce{Eigen::Vector3d::Zero()};
};

}  // namespace palp::haptics
