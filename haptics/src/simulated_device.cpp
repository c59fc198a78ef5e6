#include "palp/haptics/simulated_device.h"

#include "palp/haptics/safety.h"

namespace palp::haptics {

SimulatedDevice::SimulatedDevice(const DeviceSpec& spec, const Trajectory& trajectory,
                                 const HandModel& hand, double periodSeconds) noexcept
    : mSpec(spec), mTrajectory(trajectory), mHand(hand), mPeriod(periodSeconds) {
    sampleTrajectory(mTrajectory, 0.0, mState.position, mState.velocity);
}

DeviceState SimulatedDevice::read() noexcept {
    ++mTick;
    const double t = static_cast<double>(mTick) * mPeriod;
    Eigen::Vector3d target;
    Eigen::Vector3d targetVelocity;
    sampleTrajectory(mTrajectory, t, target, targetVelocity);
    // Semi-implicit Euler: velocity first, then position with the new velocity.
    const Eigen::Vector3d pull = mHand.stiffnessNpm * (target - mState.position) +
                                 mHand.dampingNspm * (targetVelocity - mState.velocity);
    mState.velocity += (mPeriod / mHand.massKg) * (pull + mForce);
    const Eigen::Vector3d step = mPeriod * mState.velocity;
    mWorkOnHand += mForce.dot(step);
    mState.position += step;
    mState.timestampSeconds = t;
    return mState;
}

void SimulatedDevice::write(const Eigen::Vector3d& forceN) noexcept {
    mForce = clampForce(forceN, mSpec.maxForceN);
}

}  // namespace palp::haptics
