#include "palp/haptics/devices/simulated_device.h"

#include "palp/base/bounds.h"
#include "palp/base/validate.h"
#include "palp/haptics/rendering/safety.h"

namespace palp::haptics {

void validateHandModel(const HandModel& hand, double periodSeconds) {
    requireWithin("hand model massKg", hand.massKg, bounds::kMass);
    requireWithin("hand model stiffnessNpm", hand.stiffnessNpm, bounds::kStiffness);
    requireWithin("hand model dampingNspm", hand.dampingNspm, bounds::kDamping);
    requireWithin("simulated device periodSeconds", periodSeconds, bounds::kPeriod);
    const double t = periodSeconds;
    const double stability = (hand.stiffnessNpm * t * t + 2.0 * hand.dampingNspm * t) / hand.massKg;
    if (!(stability < 4.0)) {
        throwExpected(
            "hand model",
            "(stiffnessNpm T^2 + 2 dampingNspm T) / massKg < 4, stable at the period T = " +
                formatValue(t) + " s (a heavier hand, or a softer or less damped arm)",
            formatValue(stability));
    }
}

SimulatedDevice::SimulatedDevice(const DeviceSpec& spec, const Trajectory& trajectory,
                                 const HandModel& hand, double periodSeconds)
    : mSpec(spec), mTrajectory(trajectory), mHand(hand), mPeriod(periodSeconds) {
    validateTrajectory(trajectory);
    validateHandModel(hand, periodSeconds);
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
