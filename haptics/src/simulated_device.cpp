#include "palp/haptics/simulated_device.h"

#include <cmath>
#include <numbers>

#include "palp/haptics/safety.h"

namespace palp::haptics {

void PressTrajectory::sample(double t, Eigen::Vector3d& position,
                             Eigen::Vector3d& velocity) const noexcept {
    // s(u) = (1 - cos(pi u)) / 2 on u in [0, 1]: zero velocity at both ends.
    const double pi = std::numbers::pi;
    double s = 0.0;
    double ds = 0.0;  // ds/dt
    if (pressSeconds > 0.0 && t > 0.0 && t < pressSeconds) {
        const double u = t / pressSeconds;
        s = 0.5 * (1.0 - std::cos(pi * u));
        ds = 0.5 * pi * std::sin(pi * u) / pressSeconds;
    } else if (t >= pressSeconds && t <= pressSeconds + holdSeconds) {
        s = 1.0;
    } else if (pressSeconds > 0.0 && t > pressSeconds + holdSeconds &&
               t < 2.0 * pressSeconds + holdSeconds) {
        const double u = (t - pressSeconds - holdSeconds) / pressSeconds;
        s = 0.5 * (1.0 + std::cos(pi * u));
        ds = -0.5 * pi * std::sin(pi * u) / pressSeconds;
    }
    position = start + (s * depthM) * direction;
    velocity = (ds * depthM) * direction;
}

SimulatedDevice::SimulatedDevice(const DeviceSpec& spec, const PressTrajectory& trajectory,
                                 const HandModel& hand, double periodSeconds) noexcept
    : mSpec(spec), mTrajectory(trajectory), mHand(hand), mPeriod(periodSeconds) {
    Eigen::Vector3d v;
    mTrajectory.sample(0.0, mState.position, v);
    mState.velocity = v;
}

DeviceState SimulatedDevice::read() noexcept {
    ++mTick;
    const double t = static_cast<double>(mTick) * mPeriod;
    Eigen::Vector3d target;
    Eigen::Vector3d targetVelocity;
    mTrajectory.sample(t, target, targetVelocity);
    // Semi-implicit Euler: velocity first, then position with the new velocity.
    const Eigen::Vector3d pull = mHand.stiffnessNpm * (target - mState.position) +
                                 mHand.dampingNspm * (targetVelocity - mState.velocity);
    mState.velocity += (mPeriod / mHand.massKg) * (pull + mForce);
    mState.position += mPeriod * mState.velocity;
    mState.timestampSeconds = t;
    return mState;
}

void SimulatedDevice::write(const Eigen::Vector3d& forceN) noexcept {
    mForce = clampForce(forceN, mSpec.maxForceN);
}

}  // namespace palp::haptics
