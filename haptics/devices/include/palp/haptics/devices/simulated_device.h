#pragma once
/// @file
/// A simulated device: a hand model (mass-spring-damper) follows a scripted target path, and
/// the rendered force acts on it, so the force feeds back into the motion.

#include <Eigen/Core>

#include "palp/haptics/devices/device.h"
#include "palp/haptics/devices/trajectory.h"  // PressTrajectory, Trajectory

namespace palp::haptics {

/// Hand model parameters: the hand is a point mass pulled toward the target by a spring and a
/// damper (the user's arm and grip), and pushed by the device force.
struct HandModel {
    double massKg = 0.1;          ///< kg
    double stiffnessNpm = 300.0;  ///< N/m
    double dampingNspm = 6.0;     ///< N s/m
};

/// Set-up check of @p hand against palp/base/bounds.h (massKg within kMass, stiffnessNpm within
/// kStiffness, dampingNspm within kDamping) and of its stability at @p periodSeconds: the
/// semi-implicit Euler step below is stable only while k T^2 / m + 2 c T / m < 4.
/// @throw palp::ValueError naming the member (`hand model massKg`) or the stability bound.
void validateHandModel(const HandModel& hand, double periodSeconds);

/// A Device driven by a scripted Trajectory (any path in trajectory.h; a PressTrajectory
/// converts implicitly) and a HandModel, stepped at a fixed period.
///
/// Each read() advances time by the period (the n-th read() is at t = n periodSeconds; the
/// state before the first read is the target at t = 0, at the target's velocity) and takes
/// one semi-implicit Euler step of
///   m a = k (target - x) + c (targetVelocity - v) + F,
/// velocity first, then position with the new velocity, where target is sampled at the new
/// time and F is the force last passed to write() (after clamping). In free space (F = 0) the
/// hand follows the target with the lag of this second-order filter (natural frequency
/// sqrt(k / m), damping ratio c / (2 sqrt(k m))); under a constant force F it settles
/// F / k away from a resting target.
///
/// @par Threading
/// Like any Device: read() and write() from the servo thread only.
/// @par Real-time
/// read() and write() are noexcept, allocation-free and O(1).
class SimulatedDevice final : public Device {
  public:
    /// @param spec limits reported by spec() (write() clamps the force to spec.maxForceN)
    /// @param periodSeconds simulation step per read(), s
    /// @param trajectory the target path (copied)
    /// @throw palp::ValueError from validateTrajectory(), validateHandModel() or a period outside
    /// bounds::kPeriod, naming the member.
    SimulatedDevice(const DeviceSpec& spec, const Trajectory& trajectory, const HandModel& hand,
                    double periodSeconds);

    /// Advances the hand model by one period under the last written force and returns it.
    DeviceState read() noexcept override;
    /// Sets the force on the hand, N, clamped to the spec's maximum.
    void write(const Eigen::Vector3d& forceN) noexcept override;
    const DeviceSpec& spec() const noexcept override { return mSpec; }

    /// The force applied in the next step, N (after clamping).
    const Eigen::Vector3d& appliedForce() const noexcept { return mForce; }
    /// Work the device's force has done on the hand since construction, J: the sum over steps
    /// of the applied force times the step's displacement (positive: energy into the hand).
    double workOnHand() const noexcept { return mWorkOnHand; }
    /// The scripted path the hand follows.
    const Trajectory& trajectory() const noexcept { return mTrajectory; }

  private:
    DeviceSpec mSpec;
    Trajectory mTrajectory;
    HandModel mHand;
    double mPeriod;
    long long mTick = 0;
    DeviceState mState;
    Eigen::Vector3d mForce{Eigen::Vector3d::Zero()};
    double mWorkOnHand = 0;
};

}  // namespace palp::haptics
