// Scripted trajectories (trajectory.h): press, sweep, raster, circle and sinusoid (velocity the
// derivative of position, continuity at phase boundaries, documented shapes and durations), and
// the simulated hand following them. Device logs and playback are in test_playback_device.cpp.
#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <numbers>
#include <vector>

#include "alloc_counter.h"
#include "palp/haptics/devices/simulated_device.h"
#include "palp/haptics/devices/trajectory.h"
#include "trajectory_fixtures.h"

namespace palp::haptics {
namespace {

using tfix::kT;
using tfix::touch;

constexpr double kPi = std::numbers::pi;

struct Sample {
    Eigen::Vector3d x;
    Eigen::Vector3d v;
};

Sample at(const Trajectory& path, double t) {
    Sample s;
    sampleTrajectory(path, t, s.x, s.v);
    return s;
}

/// Checks v(t) against the central difference (x(t + h) - x(t - h)) / 2h at every @p dt over
/// [t0, t1] and at @p extra times (phase boundaries and just around them).
///
/// Tolerance: on a C1 path with |acceleration| <= aMax the central difference is the mean of v
/// over [t - h, t + h], so it differs from v(t) by at most aMax h / 2 (this holds across a jump
/// in acceleration too; a jump in velocity of size dv would show as up to dv / 2). Rounding in
/// x adds about 2 eps |x| / 2h. With h = 1e-6 s and aMax ~ 1 m/s^2 the tolerance is ~1e-6 m/s,
/// far below the velocities (~0.05 m/s), so a wrong velocity formula cannot pass.
void expectVelocityIsDerivative(const Trajectory& path, double t0, double t1, double dt,
                                double aMax, const std::vector<double>& extra = {}) {
    constexpr double h = 1e-6;
    std::vector<double> times;
    for (double t = t0; t <= t1; t += dt) times.push_back(t);
    for (double tb : extra) {
        for (double d : {-2e-6, -0.5e-6, 0.0, 0.5e-6, 2e-6}) times.push_back(tb + d);
    }
    int failures = 0;
    for (double t : times) {
        const Sample s = at(path, t);
        const Eigen::Vector3d fd = (at(path, t + h).x - at(path, t - h).x) / (2.0 * h);
        const double tol = 0.5 * aMax * h + 4.0 * 2.2e-16 * (s.x.norm() + 1e-3) / h;
        const double err = (fd - s.v).norm();
        if (err > tol && failures++ < 5) {
            ADD_FAILURE() << "t = " << t << ": |v - dx/dt| = " << err << " > " << tol
                          << " (v = " << s.v.transpose() << ", fd = " << fd.transpose() << ")";
        }
    }
    EXPECT_EQ(failures, 0);
}

/// Position and velocity are continuous at @p tb: across +-delta they change by no more than
/// vMax 2 delta and aMax 2 delta.
void expectContinuousAt(const Trajectory& path, double tb, double vMax, double aMax) {
    constexpr double delta = 1e-9;
    const Sample a = at(path, tb - delta);
    const Sample b = at(path, tb + delta);
    EXPECT_LE((b.x - a.x).norm(), vMax * 2.0 * delta + 1e-15) << "position jumps at t = " << tb;
    EXPECT_LE((b.v - a.v).norm(), aMax * 2.0 * delta + 1e-12) << "velocity jumps at t = " << tb;
}

/// Peak acceleration of the cosine approach: travel pi^2 / (2 T^2).
double approachAccel(double depth, double approach, double seconds) {
    return (2.0 * depth + approach) * kPi * kPi / (2.0 * seconds * seconds);
}

// --- Press ---------------------------------------------------------------------------------

TEST(Trajectory, PressVelocityIsTheDerivativeAndNonUnitDirectionIsNormalised) {
    PressTrajectory p;
    p.direction = Eigen::Vector3d(0.0, 0.0, -3.0);  // normalised on use
    const double aMax = p.depthM * kPi * kPi / (2.0 * p.pressSeconds * p.pressSeconds);
    expectVelocityIsDerivative(p, -0.1, 2.0, 1e-3, aMax, {0.0, 0.5, 1.0, 1.5});
    Sample s = at(p, 0.5);
    EXPECT_NEAR(s.x.z(), -p.depthM, 1e-15);
    p.direction = Eigen::Vector3d::Zero();  // falls back to the default (0, 0, -1)
    s = at(p, 0.5);
    EXPECT_NEAR(s.x.z(), -p.depthM, 1e-15);
    EXPECT_TRUE(s.x.allFinite());
}

// --- Sweep ---------------------------------------------------------------------------------

SweepTrajectory testSweep() {
    SweepTrajectory s;
    s.centre = Eigen::Vector3d(0.01, 0.0, -0.02);
    s.direction = Eigen::Vector3d(2.0, 0.0, 2.0);       // not unit: normalised
    s.pressDirection = Eigen::Vector3d(0.0, 0.5, 0.0);  // not unit: normalised
    return s;
}

/// Documented phase times of a sweep (after the clamp on turnSeconds).
struct SweepTimes {
    double turn, ramp, straight, period, firstTurn;
};
SweepTimes sweepTimes(const SweepTrajectory& s) {
    SweepTimes t{};
    t.turn = std::min(s.turnSeconds, s.lengthM / (s.speedMps * (0.5 + 2.0 / kPi)));
    t.ramp = 0.5 * t.turn;
    t.straight = s.lengthM - 2.0 * s.speedMps * t.turn / kPi;
    t.period = 2.0 * t.straight / s.speedMps + 2.0 * t.turn;
    // After the speed-up (at pattern time ramp / 2), the first turn begins at pattern time
    // straight / 2 / speed.
    t.firstTurn = s.approachSeconds + t.ramp + (0.5 * t.straight / s.speedMps - 0.5 * t.ramp);
    EXPECT_NEAR(s.effectiveTurnSeconds(), t.turn, 1e-15);
    EXPECT_NEAR(s.periodSeconds(), t.period, 1e-14);
    return t;
}

std::vector<double> sweepBoundaries(const SweepTrajectory& s, int periods) {
    const SweepTimes st = sweepTimes(s);
    std::vector<double> b = {0.0, s.approachSeconds, s.approachSeconds + st.ramp};
    for (int k = 0; k < periods; ++k) {
        const double t = st.firstTurn + k * st.period;
        const double leg = st.straight / s.speedMps;
        for (double tb : {t, t + st.turn, t + st.turn + leg, t + 2 * st.turn + leg}) {
            b.push_back(tb);
        }
    }
    return b;
}

TEST(Trajectory, SweepVelocityIsTheDerivativeAndContinuousAtEveryPhase) {
    const SweepTrajectory s = testSweep();
    const SweepTimes st = sweepTimes(s);
    const double aMax = std::max(approachAccel(s.depthM, s.approachM, s.approachSeconds),
                                 s.speedMps * kPi / st.turn);
    const std::vector<double> boundaries = sweepBoundaries(s, 3);
    expectVelocityIsDerivative(s, -0.05, s.approachSeconds + 3 * st.period, 1e-3, aMax, boundaries);
    for (double tb : boundaries) expectContinuousAt(s, tb, 0.2, aMax);
}

TEST(Trajectory, SweepReversesAtHalfLengthAndKeepsThePressDepth) {
    const SweepTrajectory s = testSweep();
    const SweepTimes st = sweepTimes(s);
    const Eigen::Vector3d dir = s.direction.normalized();
    const Eigen::Vector3d press = s.pressDirection.normalized();
    // Approach: from centre - (depth + approach) press down to the pressed centre.
    EXPECT_TRUE(at(s, 0.0).x.isApprox(s.centre - (s.depthM + s.approachM) * press, 1e-14));
    EXPECT_TRUE(at(s, s.approachSeconds).x.isApprox(s.centre + s.depthM * press, 1e-14));
    EXPECT_EQ(at(s, -1.0).v, Eigen::Vector3d::Zero());

    // Over three periods: lateral extremes exactly +-L/2, reached where the velocity reverses,
    // and the depth never changes.
    std::vector<double> reversals;
    double maxX = -1.0;
    double minX = 1.0;
    double maxDepthError = 0.0;
    double previousV = 0.0;
    const double dt = 1e-5;
    for (double t = s.approachSeconds; t < s.approachSeconds + 3 * st.period; t += dt) {
        const Sample p = at(s, t);
        const Eigen::Vector3d rel = p.x - s.centre;
        const double x = rel.dot(dir);
        maxX = std::max(maxX, x);
        minX = std::min(minX, x);
        maxDepthError = std::max(maxDepthError, std::abs(rel.dot(press) - s.depthM));
        // Nothing leaves the (direction, press) plane.
        EXPECT_LT((rel - x * dir - rel.dot(press) * press).norm(), 1e-15);
        const double vx = p.v.dot(dir);
        if (previousV != 0.0 && vx * previousV < 0.0) reversals.push_back(x);
        if (vx != 0.0) previousV = vx;
    }
    // Sampling at dt misses the extreme by at most a dt^2 / 8 (a = speed pi / turn).
    const double sampling = s.speedMps * kPi / st.turn * dt * dt;
    EXPECT_NEAR(maxX, 0.5 * s.lengthM, sampling);
    EXPECT_NEAR(minX, -0.5 * s.lengthM, sampling);
    EXPECT_LT(maxDepthError, 1e-15);
    ASSERT_EQ(reversals.size(), 6u);  // two per period
    for (std::size_t i = 0; i < reversals.size(); ++i) {
        EXPECT_NEAR(std::abs(reversals[i]), 0.5 * s.lengthM, 1e-8);
        EXPECT_GT(reversals[i] * (i % 2 == 0 ? 1.0 : -1.0), 0.0);  // +, -, +, ...
    }
    // Periodic, with constant speed on the straight parts.
    const double t = st.firstTurn + 0.3 * st.period;
    EXPECT_TRUE(at(s, t).x.isApprox(at(s, t + 2 * st.period).x, 1e-12));
    EXPECT_NEAR(at(s, st.firstTurn - 1e-3).v.norm(), s.speedMps, 1e-15);
}

TEST(Trajectory, SweepClampsALongTurnAndFallsBackForZeroVectors) {
    SweepTrajectory s = testSweep();
    s.turnSeconds = 10.0;  // far too long for a 4 cm sweep at 5 cm/s
    const SweepTimes st = sweepTimes(s);
    EXPECT_LT(st.turn, 10.0);
    const double aMax = std::max(approachAccel(s.depthM, s.approachM, s.approachSeconds),
                                 s.speedMps * kPi / st.turn);
    expectVelocityIsDerivative(s, 0.0, s.approachSeconds + 2 * st.period, 1e-3, aMax,
                               sweepBoundaries(s, 2));
    double maxX = 0.0;
    for (double t = s.approachSeconds; t < s.approachSeconds + 2 * st.period; t += 1e-4) {
        maxX = std::max(maxX, std::abs((at(s, t).x - s.centre).dot(s.direction.normalized())));
    }
    EXPECT_NEAR(maxX, 0.5 * s.lengthM, 1e-7);

    s.direction = Eigen::Vector3d::Zero();
    s.pressDirection = Eigen::Vector3d(0.0, std::nan(""), 0.0);
    const Sample p = at(s, 1.0);
    ASSERT_TRUE(p.x.allFinite() && p.v.allFinite());
    EXPECT_NEAR(p.x.y() - s.centre.y(), s.depthM, 1e-15);  // fallback press (0, 1, 0)
    EXPECT_NEAR(p.x.z(), s.centre.z(), 1e-15);             // fallback sweep axis (1, 0, 0)
}

// --- Raster --------------------------------------------------------------------------------

RasterTrajectory testRaster(double extentV, double spacing) {
    RasterTrajectory r;
    r.centre = Eigen::Vector3d(0.0, 0.001, 0.0);
    r.u = Eigen::Vector3d(1.0, 0.0, 0.0);
    r.v = Eigen::Vector3d(0.5, 0.0, 2.0);  // not orthogonal to u: made orthonormal
    r.extentU = 0.02;
    r.extentV = extentV;
    r.lineSpacingM = spacing;
    r.speedMps = 0.1;
    return r;
}

double rasterAccel(const RasterTrajectory& r) {
    const double ramp = r.speedMps * kPi / (2.0 * r.rampSeconds);
    const double centripetal = r.speedMps * r.speedMps / (0.5 * r.lineSpacingM);
    return approachAccel(r.depthM, r.approachM, r.approachSeconds) + ramp + centripetal;
}

TEST(Trajectory, RasterVelocityIsTheDerivativeOverItsWholeDuration) {
    const RasterTrajectory r = testRaster(0.01, 0.002);
    const double d = r.durationSeconds();
    std::vector<double> boundaries = {0.0, r.approachSeconds, r.approachSeconds + r.rampSeconds,
                                      d - r.rampSeconds, d};
    // Line ends and half-circle ends: arc length k (line + pi rho) and k (...) + line.
    const double block = r.extentU + kPi * 0.5 * r.lineSpacingM;
    for (int k = 0; k < 6; ++k) {
        for (double s : {k * block + r.extentU, (k + 1) * block}) {
            boundaries.push_back(r.approachSeconds + 0.5 * r.rampSeconds + s / r.speedMps);
        }
    }
    expectVelocityIsDerivative(r, -0.05, d + 0.1, 2e-4, rasterAccel(r), boundaries);
    for (double tb : boundaries) expectContinuousAt(r, tb, 0.2, rasterAccel(r));
}

void expectRasterCoverage(const RasterTrajectory& r, long long lines) {
    ASSERT_EQ(r.lineCount(), lines);
    const Eigen::Vector3d uAxis = r.u.normalized();
    const Eigen::Vector3d vAxis = (r.v - r.v.dot(uAxis) * uAxis).normalized();
    const Eigen::Vector3d press = r.pressDirection.normalized();
    // Inside the rectangle in u only the straight lines run (the half circles bulge outside),
    // so the distinct v there are the lines.
    std::vector<double> levels;
    std::vector<double> minU;
    std::vector<double> maxU;
    const double dt = 1e-5;  // 1 um at 0.1 m/s
    for (double t = r.approachSeconds; t <= r.durationSeconds(); t += dt) {
        const Sample p = at(r, t);
        const Eigen::Vector3d rel = p.x - r.centre;
        EXPECT_NEAR(rel.dot(press), r.depthM, 1e-15);
        const double pu = rel.dot(uAxis);
        const double pv = rel.dot(vAxis);
        if (std::abs(pu) >= 0.5 * r.extentU) continue;
        auto it = std::find_if(levels.begin(), levels.end(),
                               [&](double level) { return std::abs(level - pv) < 1e-12; });
        std::size_t i = static_cast<std::size_t>(it - levels.begin());
        if (it == levels.end()) {
            levels.push_back(pv);
            minU.push_back(pu);
            maxU.push_back(pu);
        }
        minU[i] = std::min(minU[i], pu);
        maxU[i] = std::max(maxU[i], pu);
    }
    ASSERT_EQ(levels.size(), static_cast<std::size_t>(lines));
    for (std::size_t i = 0; i < levels.size(); ++i) {
        // In visiting order, lineSpacing apart and centred on centre.
        const double expected =
            (static_cast<double>(i) - 0.5 * static_cast<double>(lines - 1)) * r.lineSpacingM;
        EXPECT_NEAR(levels[i], expected, 1e-12) << "line " << i;
        // Each line spans the full extent (to within one sample step at full speed).
        EXPECT_NEAR(minU[i], -0.5 * r.extentU, r.speedMps * dt + 1e-12) << "line " << i;
        EXPECT_NEAR(maxU[i], 0.5 * r.extentU, r.speedMps * dt + 1e-12) << "line " << i;
    }
    // Ends where documented and stays there, at rest.
    const double endU = (lines % 2 == 1 ? 0.5 : -0.5) * r.extentU;
    const double endV = 0.5 * static_cast<double>(lines - 1) * r.lineSpacingM;
    EXPECT_NEAR(r.endOffset().x(), endU, 1e-15);
    EXPECT_NEAR(r.endOffset().y(), endV, 1e-15);
    EXPECT_NEAR(r.startOffset().x(), -0.5 * r.extentU, 1e-15);
    EXPECT_NEAR(r.startOffset().y(), -endV, 1e-15);
    const Eigen::Vector3d end = r.centre + endU * uAxis + endV * vAxis + r.depthM * press;
    for (double t : {r.durationSeconds(), r.durationSeconds() + 5.0}) {
        const Sample p = at(r, t);
        EXPECT_LT((p.x - end).norm(), 1e-14) << "t = " << t;
        EXPECT_EQ(p.v.norm(), 0.0);
    }
}

TEST(Trajectory, RasterVisitsEveryLineAndEndsWhereDocumented) {
    expectRasterCoverage(testRaster(0.01, 0.002), 6);   // even count: ends at -u
    expectRasterCoverage(testRaster(0.012, 0.003), 5);  // odd count: ends at +u
    expectRasterCoverage(testRaster(0.011, 0.002), 6);  // not a multiple: 6 lines, centred
    expectRasterCoverage(testRaster(0.0, 0.002), 1);
}

TEST(Trajectory, RasterDurationIsExact) {
    const RasterTrajectory r = testRaster(0.01, 0.002);
    const double rho = 0.5 * r.lineSpacingM;
    const double length = 6 * r.extentU + 5 * kPi * rho;
    EXPECT_NEAR(r.pathLengthM(), length, 1e-15);
    const double d = r.durationSeconds();
    EXPECT_NEAR(d, r.approachSeconds + r.rampSeconds + length / r.speedMps, 1e-12);
    // The speed profile pins the duration: full speed until d - ramp, half speed at the middle
    // of the slow-down, zero at d (and not before).
    EXPECT_NEAR(at(r, d - r.rampSeconds).v.norm(), r.speedMps, 1e-12);
    EXPECT_NEAR(at(r, d - 0.5 * r.rampSeconds).v.norm(), 0.5 * r.speedMps, 1e-12);
    EXPECT_GT(at(r, d - 1e-4).v.norm(), 0.0);
    EXPECT_EQ(at(r, d).v.norm(), 0.0);
    EXPECT_NEAR(at(r, r.approachSeconds + 0.5 * r.rampSeconds).v.norm(), 0.5 * r.speedMps, 1e-12);
}

// --- Circle --------------------------------------------------------------------------------

TEST(Trajectory, CircleRadiusFrequencyAndDerivative) {
    CircleTrajectory c;
    c.centre = Eigen::Vector3d(0.0, 0.0, 0.03);
    c.u = Eigen::Vector3d(0.0, 0.0, 1.0);
    c.v = Eigen::Vector3d(1.0, 0.0, 0.0);
    c.frequencyHz = 2.0;
    const double w = 2.0 * kPi * c.frequencyHz;
    const double aMax = approachAccel(c.depthM, c.approachM, c.approachSeconds) +
                        w * w * c.radiusM + w * c.radiusM * kPi / (2.0 * c.rampSeconds);
    const double start = c.approachSeconds + c.rampSeconds;
    expectVelocityIsDerivative(c, -0.05, start + 1.0, 5e-4, aMax, {0.0, c.approachSeconds, start});
    for (double tb : {0.0, c.approachSeconds, start}) expectContinuousAt(c, tb, 1.0, aMax);

    // Approach onto the start point centre + r u.
    const Eigen::Vector3d press = c.pressDirection;
    EXPECT_TRUE(
        at(c, c.approachSeconds).x.isApprox(c.centre + c.radiusM * c.u + c.depthM * press, 1e-14));
    // After the spin-up: on the circle, at speed 2 pi f r, a quarter turn (from u toward v)
    // every 1 / 4f, the same point every 1 / f.
    const Eigen::Vector3d hub = c.centre + c.depthM * press;
    for (double t = start; t < start + 2.0; t += 0.01) {
        const Sample p = at(c, t);
        EXPECT_NEAR((p.x - hub).norm(), c.radiusM, 1e-15);
        EXPECT_NEAR(p.v.norm(), w * c.radiusM, 1e-14);
        EXPECT_NEAR(p.v.dot(p.x - hub), 0.0, 1e-15);
        const Eigen::Vector3d a = (p.x - hub) / c.radiusM;
        const Eigen::Vector3d b = (at(c, t + 0.25 / c.frequencyHz).x - hub) / c.radiusM;
        EXPECT_NEAR(a.cross(b).dot(c.u.cross(c.v)), 1.0, 1e-12);  // +90 degrees
        EXPECT_LT((at(c, t + 1.0 / c.frequencyHz).x - p.x).norm(), 1e-15);
    }
}

// --- Sinusoid ------------------------------------------------------------------------------

TEST(Trajectory, SinusoidEnvelopeGrowsLinearlyThenHolds) {
    SinusoidTrajectory s;
    s.start = Eigen::Vector3d(0.0, 0.002, 0.0);
    s.direction = Eigen::Vector3d(0.0, 2.0, 0.0);
    s.amplitudeM = 0.003;
    s.frequencyHz = 2.0;
    s.growSeconds = 2.5;  // a whole number of half periods: C1
    const double w = 2.0 * kPi * s.frequencyHz;
    const double aMax = s.amplitudeM * w * w + 2.0 * s.amplitudeM / s.growSeconds * w;
    expectVelocityIsDerivative(s, -0.1, 4.0, 1e-3, aMax, {0.0, s.growSeconds});
    expectContinuousAt(s, s.growSeconds, 1.0, aMax);
    expectContinuousAt(s, 0.0, 1.0, aMax);

    const Eigen::Vector3d dir = s.direction.normalized();
    auto envelope = [&](double t) { return s.amplitudeM * std::clamp(t / s.growSeconds, 0., 1.); };
    for (double t = 0.0; t < 4.0; t += 1e-3) {
        const double disp = (at(s, t).x - s.start).dot(dir);
        EXPECT_LE(std::abs(disp), envelope(t) + 1e-15) << "t = " << t;
    }
    // Peaks (sin = +-1) touch the envelope: linear growth, then the full amplitude.
    for (int k = 0; k < 24; ++k) {
        const double t = (0.25 + 0.5 * k) / s.frequencyHz;
        const double disp = (at(s, t).x - s.start).dot(dir);
        EXPECT_NEAR(std::abs(disp), envelope(t), 1e-15) << "peak " << k;
    }
}

TEST(Trajectory, SinusoidVelocityStepAtTheEndOfGrowthIsAsDocumented) {
    SinusoidTrajectory s;
    s.frequencyHz = 1.0;
    s.growSeconds = 1.1;  // not a whole number of half periods
    const double before = at(s, s.growSeconds - 1e-12).v.y();
    const double after = at(s, s.growSeconds).v.y();
    const double step = -(s.amplitudeM / s.growSeconds) * std::sin(2 * kPi * s.growSeconds);
    EXPECT_NEAR(after - before, step, 1e-9);
    EXPECT_GT(std::abs(step), 1e-4);
    // No growth: starts abruptly at 2 pi f A.
    s.growSeconds = 0.0;
    EXPECT_NEAR(at(s, 0.0).v.y(), 2 * kPi * s.amplitudeM, 1e-15);
    EXPECT_EQ(at(s, -1e-9).v.y(), 0.0);
}

// --- SimulatedDevice with any trajectory -----------------------------------------------------

TEST(SimulatedDevice, FreeHandFollowsASweepWithBoundedLag) {
    const HandModel hand;
    const SweepTrajectory s = testSweep();
    const SweepTimes st = sweepTimes(s);
    SimulatedDevice dev(touch(), s, hand, kT);
    // Tracking error e = target - x obeys m e'' + c e' + k e = m a_target. For this damping ratio
    // (0.55) the L1 norm of the normalised impulse response is below 1.3, so |e| <= 1.3 m a / k;
    // 2 m a / k leaves room for the Euler step.
    const double aMax = std::max(approachAccel(s.depthM, s.approachM, s.approachSeconds),
                                 s.speedMps * kPi / st.turn);
    const double bound = 2.0 * hand.massKg * aMax / hand.stiffnessNpm;
    const Eigen::Vector3d dir = s.direction.normalized();
    const Eigen::Vector3d press = s.pressDirection.normalized();
    double maxLag = 0.0;
    double maxX = 0.0;
    double maxDepthError = 0.0;
    const int ticks = static_cast<int>((s.approachSeconds + 3 * st.period) / kT);
    for (int n = 1; n <= ticks; ++n) {
        const DeviceState d = dev.read();
        ASSERT_NEAR(d.timestampSeconds, n * kT, 1e-12);
        const Sample target = at(s, d.timestampSeconds);
        maxLag = std::max(maxLag, (target.x - d.position).norm());
        maxX = std::max(maxX, (d.position - s.centre).dot(dir));
        if (d.timestampSeconds > s.approachSeconds + 0.5) {
            maxDepthError =
                std::max(maxDepthError, std::abs((d.position - s.centre).dot(press) - s.depthM));
        }
    }
    EXPECT_LT(maxLag, bound);
    EXPECT_GT(maxLag, 0.05 * bound);  // it does lag: the hand is not glued to the target
    EXPECT_NEAR(maxX, 0.5 * s.lengthM, bound);
    EXPECT_LT(maxDepthError, 1e-6);  // constant depth target: the transient has died out
}

TEST(SimulatedDevice, ConstantOpposingForceShiftsTheSteadyStateByFOverK) {
    const HandModel hand;
    const SweepTrajectory s = testSweep();
    const Eigen::Vector3d press = s.pressDirection.normalized();
    const double f = 1.5;  // N, below the Touch's 3.3 N
    SimulatedDevice free(touch(), s, hand, kT);
    SimulatedDevice pushed(touch(), s, hand, kT);
    DeviceState a;
    DeviceState b;
    for (int n = 0; n < 2000; ++n) {
        a = free.read();
        b = pushed.read();
        pushed.write(-f * press);  // the tissue pushes back out of the surface
    }
    const Eigen::Vector3d shift = b.position - a.position;
    EXPECT_NEAR(shift.dot(press), -f / hand.stiffnessNpm, 1e-7);
    // The lateral motion is linear and independent of a force along press.
    EXPECT_LT((shift - shift.dot(press) * press).norm(), 1e-12);
}

TEST(SimulatedDevice, EveryTrajectoryIsAllocationFree) {
    const std::vector<Trajectory> paths = {PressTrajectory{}, testSweep(), testRaster(0.01, 0.002),
                                           CircleTrajectory{}, SinusoidTrajectory{}};
    for (const Trajectory& path : paths) {
        SimulatedDevice dev(touch(), path, HandModel{}, kT);
        Device& d = dev;
        double sum = 0.0;
        const std::uint64_t before = test::allocationCount();
        for (int n = 0; n < 1000; ++n) {
            sum += d.read().position.norm();
            d.write(Eigen::Vector3d(0.0, -0.5, 0.0));
        }
        EXPECT_EQ(test::allocationCount(), before) << "trajectory " << path.index();
        EXPECT_TRUE(std::isfinite(sum));
    }
}

}  // namespace
}  // namespace palp::haptics
