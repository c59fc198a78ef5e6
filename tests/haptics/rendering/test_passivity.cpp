#include <gtest/gtest.h>

#include <cmath>
#include <numbers>

#include "alloc_counter.h"
#include "palp/haptics/rendering/passivity.h"

namespace palp::haptics {
namespace {

constexpr double kT = 1e-3;

// Position on a closed loop through the origin (a 2 cm circle in the xy plane plus a z wobble),
// one revolution every `period` ticks; tick 0 is at the origin, where the spring is relaxed.
Eigen::Vector3d loopPosition(int tick, int period) {
    const double a = 2.0 * std::numbers::pi * tick / period;
    return Eigen::Vector3d(0.02 * (1.0 - std::cos(a)), 0.02 * std::sin(a), 0.005 * std::sin(2 * a));
}

TEST(Passivity, SpringOnClosedLoopsStaysPassive) {
    const double k = 800.0;  // N/m
    PassivityController observer(kT, /*enabled=*/false);
    Eigen::Vector3d prev = loopPosition(0, 500);
    double minEnergy = 0.0;
    for (int n = 1; n <= 5000; ++n) {  // ten loops
        const Eigen::Vector3d x = loopPosition(n, 500);
        const Eigen::Vector3d v = (x - prev) / kT;  // backward difference, as a device reports
        const Eigen::Vector3d f = -k * x;           // spring to the origin, force on the user
        const Eigen::Vector3d out = observer.update(f, v);
        EXPECT_EQ(out, f);  // observer only: force untouched
        minEnergy = std::min(minEnergy, observer.energy());
        // Discrete bound: W(n) >= k |x(n)|^2 / 2 (the sampled spring stores at least that).
        EXPECT_GE(observer.energy(), 0.5 * k * x.squaredNorm() * (1 - 1e-9));
        prev = x;
    }
    EXPECT_GE(minEnergy, -1e-12);
}

TEST(Passivity, NegativeDampingIsDetected) {
    const double c = 5.0;  // N s/m, active: pushes along the velocity
    PassivityController observer(kT, /*enabled=*/false);
    Eigen::Vector3d prev = loopPosition(0, 400);
    for (int n = 1; n <= 400; ++n) {
        const Eigen::Vector3d x = loopPosition(n, 400);
        const Eigen::Vector3d v = (x - prev) / kT;
        observer.update(c * v, v);
        prev = x;
    }
    EXPECT_LT(observer.energy(), -1e-3);
    EXPECT_EQ(observer.addedDamping(), 0.0);
    EXPECT_EQ(observer.dissipatedEnergy(), 0.0);
}

TEST(Passivity, ControllerKeepsActiveElementPassive) {
    const double c = 5.0;
    PassivityController controller(kT, /*enabled=*/true);
    Eigen::Vector3d prev = loopPosition(0, 400);
    double maxAlpha = 0.0;
    double work = 0.0;  // independent bookkeeping of -T sum F_out . v
    for (int n = 1; n <= 2000; ++n) {
        const Eigen::Vector3d x = loopPosition(n, 400);
        const Eigen::Vector3d v = (x - prev) / kT;
        const Eigen::Vector3d f = c * v;
        const Eigen::Vector3d out = controller.update(f, v);
        work -= kT * out.dot(v);
        EXPECT_GE(controller.energy(), -1e-12);
        // The added damping acts along -v with the reported coefficient.
        EXPECT_TRUE((f - out).isApprox(controller.addedDamping() * v, 1e-12) ||
                    controller.addedDamping() == 0.0);
        // Negative damping c is cancelled exactly by alpha = c once W has reached zero.
        if (n > 1) {
            EXPECT_NEAR(controller.addedDamping(), c, 1e-6 * c);
        }
        maxAlpha = std::max(maxAlpha, controller.addedDamping());
        prev = x;
    }
    EXPECT_GT(maxAlpha, 0.0);
    EXPECT_GT(controller.dissipatedEnergy(), 0.0);
    EXPECT_NEAR(controller.energy(), work, 1e-9);
}

TEST(Passivity, DampingCapThenForceCutKeepsEnergyNonNegative) {
    // Net active damping 5 N s/m against a 1 N s/m damping cap: the cap binds and the rest is
    // cut from the force along v, so W stays at zero and the force on the hand does no work.
    PassivityController controller(kT, true, /*maxDampingNspm=*/1.0);
    const Eigen::Vector3d v(0.1, 0, 0);
    for (int n = 0; n < 100; ++n) {
        const Eigen::Vector3d out = controller.update(5.0 * v + Eigen::Vector3d(0, 2, 0), v);
        EXPECT_DOUBLE_EQ(controller.addedDamping(), 1.0);
        EXPECT_NEAR(controller.forceCut(), 0.4, 1e-12);  // (5 - 1) N s/m * 0.1 m/s
        EXPECT_NEAR(out.x(), 0.0, 1e-12);                // nothing left along v
        EXPECT_EQ(out.y(), 2.0);                         // the rest of the force is kept
        EXPECT_GE(controller.energy(), 0.0);
    }
    EXPECT_NEAR(controller.energy(), 0.0, 1e-15);
    EXPECT_NEAR(controller.dissipatedEnergy(), 100 * kT * 5.0 * 0.01, 1e-12);
    // Observer only (disabled): the same input drives W negative.
    PassivityController observer(kT, false, 1.0);
    for (int n = 0; n < 100; ++n) observer.update(5.0 * v, v);
    EXPECT_NEAR(observer.energy(), -5e-3, 1e-12);
}

TEST(Passivity, OutputIsClampedToTheForceLimitAndBookedAsSent) {
    PassivityController controller(kT, true, 2.0, /*maxForceN=*/1.5);
    const Eigen::Vector3d v(0, 0.05, 0);
    double booked = 0;
    for (int n = 0; n < 200; ++n) {
        // A stiff spring pushing against v (absorbing) then along it (returning energy).
        const Eigen::Vector3d f = (n < 100 ? -1.0 : 1.0) * Eigen::Vector3d(0, 3.0, 0.5);
        const Eigen::Vector3d out = controller.update(f, v);
        EXPECT_LE(out.norm(), 1.5 + 1e-12);
        EXPECT_TRUE(out.allFinite());
        booked -= kT * out.dot(v);
        EXPECT_GE(controller.energy(), -1e-15);
    }
    EXPECT_NEAR(controller.energy(), booked, 1e-15);
}

TEST(Passivity, ZeroVelocityAndReset) {
    PassivityController controller(kT);
    const Eigen::Vector3d f(1, 2, 3);
    EXPECT_EQ(controller.update(f, Eigen::Vector3d::Zero()), f);
    EXPECT_EQ(controller.energy(), 0.0);
    controller.update(f, Eigen::Vector3d(1, 0, 0));
    controller.reset();
    EXPECT_EQ(controller.energy(), 0.0);
    EXPECT_EQ(controller.dissipatedEnergy(), 0.0);
}

TEST(Passivity, UpdateDoesNotAllocate) {
    PassivityController controller(kT);
    Eigen::Vector3d acc = Eigen::Vector3d::Zero();
    const std::uint64_t before = test::allocationCount();
    for (int n = 0; n < 1000; ++n) {
        const Eigen::Vector3d v(std::sin(n * 0.01), 0.1, 0.0);
        acc += controller.update(3.0 * v, v);
    }
    EXPECT_EQ(test::allocationCount(), before);
    EXPECT_TRUE(acc.allFinite());
}

}  // namespace
}  // namespace palp::haptics
