#include "palp/haptics/devices/trajectory.h"

#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <numbers>
#include <string>

#include "palp/base/bounds.h"
#include "palp/base/validate.h"

namespace palp::haptics {
namespace {

constexpr double kPi = std::numbers::pi;

/// @p x when positive and finite, else 0 (NaN and negatives count as zero).
double nonNegative(double x) noexcept { return (x > 0.0 && std::isfinite(x)) ? x : 0.0; }

/// @p x when finite, else 0.
double finiteOrZero(double x) noexcept { return std::isfinite(x) ? x : 0.0; }

/// @p a normalised, or @p fallback (already unit) when @p a is zero or not finite.
Eigen::Vector3d unitOr(const Eigen::Vector3d& a, const Eigen::Vector3d& fallback) noexcept {
    const double n = a.norm();
    if (!(n > 1e-300) || !std::isfinite(n)) return fallback;
    return a / n;
}

/// Orthonormal in-plane axes from (u, v) as documented in trajectory.h.
void planeAxes(const Eigen::Vector3d& u, const Eigen::Vector3d& v, const Eigen::Vector3d& press,
               Eigen::Vector3d& uOut, Eigen::Vector3d& vOut) noexcept {
    uOut = unitOr(u, Eigen::Vector3d::UnitX());
    const Eigen::Vector3d vIn = v.allFinite() ? v : Eigen::Vector3d::Zero();
    const Eigen::Vector3d vPerp = vIn - vIn.dot(uOut) * uOut;
    // Relative test: a v almost parallel to u leaves only rounding noise.
    if (vPerp.norm() > 1e-9 * vIn.norm()) {
        vOut = vPerp.normalized();
        return;
    }
    const Eigen::Vector3d p = unitOr(press, Eigen::Vector3d::UnitY());
    const Eigen::Vector3d c = p.cross(uOut);
    vOut = c.norm() > 1e-9 ? Eigen::Vector3d(c.normalized()) : uOut.unitOrthogonal();
}

/// Cosine profile s(x) = (1 - cos(pi x)) / 2 on [0, 1] (clamped outside) and ds/dx.
void cosineStep(double x, double& s, double& ds) noexcept {
    if (x <= 0.0) {
        s = 0.0;
        ds = 0.0;
    } else if (x >= 1.0) {
        s = 1.0;
        ds = 0.0;
    } else {
        s = 0.5 * (1.0 - std::cos(kPi * x));
        ds = 0.5 * kPi * std::sin(kPi * x);
    }
}

/// Distance and speed after time @p tau of a start from rest that reaches @p speed over
/// @p ramp with speed(tau) = speed (1 - cos(pi tau / ramp)) / 2, then keeps it.
void rampUp(double tau, double speed, double ramp, double& s, double& ds) noexcept {
    if (tau <= 0.0) {
        s = 0.0;
        ds = 0.0;
    } else if (tau < ramp) {
        const double w = kPi / ramp;
        s = speed * (0.5 * tau - std::sin(w * tau) / (2.0 * w));
        ds = speed * 0.5 * (1.0 - std::cos(w * tau));
    } else {
        s = speed * (tau - 0.5 * ramp);
        ds = speed;
    }
}

/// Approach of the sweep, raster and circle: the offset along the press direction (from the
/// surface point, positive into the surface) and its rate at time t.
void approach(double t, double depth, double approachM, double seconds, double& d,
              double& dd) noexcept {
    const double travel = 2.0 * depth + approachM;  // from -(depth + approach) to +depth
    double s = 1.0;
    double ds = 0.0;
    if (t < 0.0) {
        s = 0.0;
    } else if (seconds > 0.0) {
        cosineStep(t / seconds, s, ds);
        ds /= seconds;
    }
    d = -(depth + approachM) + travel * s;
    dd = travel * ds;
}

/// Raster geometry with the parameters sanitised, shared by the member functions.
struct RasterShape {
    double lineLength;  // m, along u
    double spacing;     // m, along v (0 with one line)
    long long lines;
    double radius;  // half-circle radius, m
    double block;   // arc length of one line and the following half circle, m
    double length;  // whole path, m
    double speed;   // m/s
    double ramp;    // effective speed-up time, s

    explicit RasterShape(const RasterTrajectory& r) noexcept {
        lineLength = nonNegative(r.extentU);
        const double extentV = nonNegative(r.extentV);
        const double spacingIn = nonNegative(r.lineSpacingM);
        lines = 1;
        if (spacingIn > 0.0 && extentV > 0.0) {
            // The 1e-9 keeps an exact multiple (0.06 / 0.002 = 29.999999999999996) at its count.
            const double n = std::floor(extentV / spacingIn * (1.0 + 1e-9)) + 1.0;
            lines = static_cast<long long>(std::min(n, 1e7));
        }
        spacing = lines > 1 ? spacingIn : 0.0;
        radius = 0.5 * spacing;
        block = lineLength + kPi * radius;
        length =
            static_cast<double>(lines) * lineLength + static_cast<double>(lines - 1) * kPi * radius;
        speed = nonNegative(r.speedMps);
        ramp = speed > 0.0 ? std::min(nonNegative(r.rampSeconds), length / speed) : 0.0;
    }

    double lineV(long long i) const noexcept {
        return (static_cast<double>(i) - 0.5 * static_cast<double>(lines - 1)) * spacing;
    }

    /// (u, v) offset and unit tangent at arc length @p s in [0, length].
    void at(double s, Eigen::Vector2d& p, Eigen::Vector2d& tangent) const noexcept {
        long long k = block > 0.0 ? static_cast<long long>(std::floor(s / block)) : 0;
        k = std::clamp(k, 0LL, lines - 1);
        const double r = s - static_cast<double>(k) * block;
        const double sign = (k % 2 == 0) ? 1.0 : -1.0;
        const double half = 0.5 * lineLength;
        if (k == lines - 1 || r <= lineLength) {
            const double along = std::min(r, lineLength);
            p = Eigen::Vector2d(sign * (-half + along), lineV(k));
            tangent = Eigen::Vector2d(sign, 0.0);
            return;
        }
        const double phi = (r - lineLength) / radius;  // radius > 0 here: lines > 1
        p = Eigen::Vector2d(sign * (half + radius * std::sin(phi)),
                            lineV(k) + radius * (1.0 - std::cos(phi)));
        tangent = Eigen::Vector2d(sign * std::cos(phi), std::sin(phi));
    }

    /// Arc length and its rate at time @p tau after the approach.
    void progress(double tau, double& s, double& ds) const noexcept {
        if (!(speed > 0.0) || tau <= 0.0) {
            s = 0.0;
            ds = 0.0;
            return;
        }
        const double total = ramp + length / speed;
        if (tau >= total) {
            s = length;
            ds = 0.0;
            return;
        }
        const double slowStart = total - ramp;
        if (tau <= slowStart || ramp <= 0.0) {
            rampUp(tau, speed, ramp, s, ds);
            return;
        }
        // The slow-down mirrors the speed-up in time.
        rampUp(total - tau, speed, ramp, s, ds);
        s = length - s;
    }
};

}  // namespace

void PressTrajectory::sample(double t, Eigen::Vector3d& position,
                             Eigen::Vector3d& velocity) const noexcept {
    // s(u) = (1 - cos(pi u)) / 2 on u in [0, 1]: zero velocity at both ends.
    const Eigen::Vector3d dir = unitOr(direction, Eigen::Vector3d(0.0, 0.0, -1.0));
    const double press = nonNegative(pressSeconds);
    const double hold = nonNegative(holdSeconds);
    const double depth = nonNegative(depthM);
    double s = 0.0;
    double ds = 0.0;  // ds/dt
    if (t < 0.0) {
        s = 0.0;
    } else if (t < press) {
        cosineStep(t / press, s, ds);
        ds /= press;
    } else if (t <= press + hold) {
        s = 1.0;
    } else if (t < 2.0 * press + hold) {
        cosineStep((t - press - hold) / press, s, ds);
        s = 1.0 - s;
        ds = -ds / press;
    }
    position = start + (s * depth) * dir;
    velocity = (ds * depth) * dir;
    if (skin) skin->apply(position, velocity);
}

double SweepTrajectory::effectiveTurnSeconds() const noexcept {
    const double length = nonNegative(lengthM);
    const double speed = nonNegative(speedMps);
    if (!(length > 0.0 && speed > 0.0)) return 0.0;
    return std::min(nonNegative(turnSeconds), length / (speed * (0.5 + 2.0 / kPi)));
}

double SweepTrajectory::periodSeconds() const noexcept {
    const double speed = nonNegative(speedMps);
    const double turn = effectiveTurnSeconds();
    if (!(nonNegative(lengthM) > 0.0 && speed > 0.0)) return 0.0;
    return 2.0 * (nonNegative(lengthM) - 2.0 * speed * turn / kPi) / speed + 2.0 * turn;
}

void SweepTrajectory::sample(double t, Eigen::Vector3d& position,
                             Eigen::Vector3d& velocity) const noexcept {
    const Eigen::Vector3d dir = unitOr(direction, Eigen::Vector3d::UnitX());
    const Eigen::Vector3d press = unitOr(pressDirection, Eigen::Vector3d::UnitY());
    const double depth = nonNegative(depthM);
    const double approachTime = nonNegative(approachSeconds);
    double d = 0.0;
    double dd = 0.0;
    approach(t, depth, nonNegative(approachM), approachTime, d, dd);

    const double length = nonNegative(lengthM);
    const double speed = nonNegative(speedMps);
    double x = 0.0;
    double dx = 0.0;
    const double tau = t - approachTime;
    if (tau > 0.0 && length > 0.0 && speed > 0.0) {
        const double turn = effectiveTurnSeconds();
        const double ramp = 0.5 * turn;
        if (tau < ramp) {
            rampUp(tau, speed, ramp, x, dx);
        } else {
            // Pattern time: 0 at x = 0 moving toward +direction; the speed-up ends at
            // x = speed ramp / 2, i.e. pattern time ramp / 2.
            const double straight = length - 2.0 * speed * turn / kPi;  // >= 0 by the clamp
            const double a1 = 0.5 * straight / speed;                   // to the first turn
            const double period = periodSeconds();
            const double p = std::fmod(tau - 0.5 * ramp, period);
            const double bulge = speed * turn / kPi;
            const double w = turn > 0.0 ? kPi / turn : 0.0;
            const double b1 = a1 + turn;              // end of the + turn
            const double b2 = b1 + straight / speed;  // start of the - turn
            const double b3 = b2 + turn;              // end of the - turn
            if (p < a1) {
                x = speed * p;
                dx = speed;
            } else if (p < b1) {
                x = 0.5 * straight + bulge * std::sin(w * (p - a1));
                dx = speed * std::cos(w * (p - a1));
            } else if (p < b2) {
                x = 0.5 * straight - speed * (p - b1);
                dx = -speed;
            } else if (p < b3) {
                x = -0.5 * straight - bulge * std::sin(w * (p - b2));
                dx = -speed * std::cos(w * (p - b2));
            } else {
                x = -0.5 * straight + speed * (p - b3);
                dx = speed;
            }
        }
    }
    position = centre + d * press + x * dir;
    velocity = dd * press + dx * dir;
    if (skin) skin->apply(position, velocity);
}

long long RasterTrajectory::lineCount() const noexcept { return RasterShape(*this).lines; }

double RasterTrajectory::pathLengthM() const noexcept { return RasterShape(*this).length; }

double RasterTrajectory::durationSeconds() const noexcept {
    const RasterShape shape(*this);
    const double moving = shape.speed > 0.0 ? shape.ramp + shape.length / shape.speed : 0.0;
    return nonNegative(approachSeconds) + moving;
}

Eigen::Vector2d RasterTrajectory::startOffset() const noexcept {
    const RasterShape shape(*this);
    Eigen::Vector2d p;
    Eigen::Vector2d tangent;
    shape.at(0.0, p, tangent);
    return p;
}

Eigen::Vector2d RasterTrajectory::endOffset() const noexcept {
    const RasterShape shape(*this);
    Eigen::Vector2d p;
    Eigen::Vector2d tangent;
    shape.at(shape.length, p, tangent);
    return p;
}

void RasterTrajectory::sample(double t, Eigen::Vector3d& position,
                              Eigen::Vector3d& velocity) const noexcept {
    const RasterShape shape(*this);
    Eigen::Vector3d uAxis;
    Eigen::Vector3d vAxis;
    planeAxes(u, v, pressDirection, uAxis, vAxis);
    const Eigen::Vector3d press = unitOr(pressDirection, Eigen::Vector3d::UnitY());
    const double approachTime = nonNegative(approachSeconds);
    double d = 0.0;
    double dd = 0.0;
    approach(t, nonNegative(depthM), nonNegative(approachM), approachTime, d, dd);
    double s = 0.0;
    double ds = 0.0;
    shape.progress(t - approachTime, s, ds);
    Eigen::Vector2d p;
    Eigen::Vector2d tangent;
    shape.at(s, p, tangent);
    position = centre + p.x() * uAxis + p.y() * vAxis + d * press;
    velocity = ds * (tangent.x() * uAxis + tangent.y() * vAxis) + dd * press;
    if (skin) skin->apply(position, velocity);
}

void CircleTrajectory::sample(double t, Eigen::Vector3d& position,
                              Eigen::Vector3d& velocity) const noexcept {
    Eigen::Vector3d uAxis;
    Eigen::Vector3d vAxis;
    planeAxes(u, v, pressDirection, uAxis, vAxis);
    const Eigen::Vector3d press = unitOr(pressDirection, Eigen::Vector3d::UnitY());
    const double approachTime = nonNegative(approachSeconds);
    double d = 0.0;
    double dd = 0.0;
    approach(t, nonNegative(depthM), nonNegative(approachM), approachTime, d, dd);
    const double radius = nonNegative(radiusM);
    const double f = finiteOrZero(frequencyHz);
    // Turns (revolutions) rather than radians, reduced modulo 1 so that the angle keeps its
    // precision after hours.
    double turns = 0.0;
    double rate = 0.0;  // turns per second
    rampUp(t - approachTime, f, nonNegative(rampSeconds), turns, rate);
    const double theta = 2.0 * kPi * (turns - std::floor(turns));
    const double c = std::cos(theta);
    const double s = std::sin(theta);
    position = centre + radius * (c * uAxis + s * vAxis) + d * press;
    velocity = (2.0 * kPi * rate * radius) * (c * vAxis - s * uAxis) + dd * press;
    if (skin) skin->apply(position, velocity);
}

void SinusoidTrajectory::sample(double t, Eigen::Vector3d& position,
                                Eigen::Vector3d& velocity) const noexcept {
    const Eigen::Vector3d dir = unitOr(direction, Eigen::Vector3d::UnitY());
    if (!(t >= 0.0)) {
        position = start;
        velocity.setZero();
        if (skin) skin->apply(position, velocity);
        return;
    }
    const double amplitude = nonNegative(amplitudeM);
    const double grow = nonNegative(growSeconds);
    const double w = 2.0 * kPi * finiteOrZero(frequencyHz);
    double a = amplitude;
    double da = 0.0;
    if (grow > 0.0 && t < grow) {
        a = amplitude * t / grow;
        da = amplitude / grow;
    }
    const double s = std::sin(w * t);
    position = start + (a * s) * dir;
    velocity = (da * s + a * w * std::cos(w * t)) * dir;
    if (skin) skin->apply(position, velocity);
}

void sampleTrajectory(const Trajectory& trajectory, double t, Eigen::Vector3d& position,
                      Eigen::Vector3d& velocity) noexcept {
    std::visit([&](const auto& path) { path.sample(t, position, velocity); }, trajectory);
}

namespace {

/// Checks one trajectory's members, each named `<Type> <member>`.
class TrajectoryCheck {
  public:
    explicit TrajectoryCheck(const char* type) : mType(type) {}

    const TrajectoryCheck& point(const char* member, const Eigen::Vector3d& p) const {
        for (int i = 0; i < 3; ++i) requireWithin(name(member), p[i], bounds::kPosition);
        return *this;
    }
    const TrajectoryCheck& direction(const char* member, const Eigen::Vector3d& d) const {
        if (!d.allFinite()) {
            throwExpected(name(member), "a finite vector",
                          "(" + formatValue(d.x()) + ", " + formatValue(d.y()) + ", " +
                              formatValue(d.z()) + ")");
        }
        return *this;
    }
    const TrajectoryCheck& scalar(const char* member, double v, const Bounds& b) const {
        requireWithin(name(member), v, b);
        return *this;
    }

  private:
    std::string name(const char* member) const { return std::string(mType) + " " + member; }
    const char* mType;
};

void check(const PressTrajectory& p) {
    TrajectoryCheck("PressTrajectory")
        .point("start", p.start)
        .direction("direction", p.direction)
        .scalar("depthM", p.depthM, bounds::kSpan)
        .scalar("pressSeconds", p.pressSeconds, bounds::kPositiveDuration)
        .scalar("holdSeconds", p.holdSeconds, bounds::kDuration);
}

void check(const SweepTrajectory& s) {
    TrajectoryCheck("SweepTrajectory")
        .point("centre", s.centre)
        .direction("direction", s.direction)
        .direction("pressDirection", s.pressDirection)
        .scalar("lengthM", s.lengthM, bounds::kSpan)
        .scalar("speedMps", s.speedMps, bounds::kSpeed)
        .scalar("depthM", s.depthM, bounds::kSpan)
        .scalar("approachM", s.approachM, bounds::kSpan)
        .scalar("approachSeconds", s.approachSeconds, bounds::kDuration)
        .scalar("turnSeconds", s.turnSeconds, bounds::kDuration);
}

void check(const RasterTrajectory& r) {
    TrajectoryCheck("RasterTrajectory")
        .point("centre", r.centre)
        .direction("u", r.u)
        .direction("v", r.v)
        .direction("pressDirection", r.pressDirection)
        .scalar("extentU", r.extentU, bounds::kSpan)
        .scalar("extentV", r.extentV, bounds::kSpan)
        .scalar("lineSpacingM", r.lineSpacingM, bounds::kSpan)
        .scalar("speedMps", r.speedMps, bounds::kSpeed)
        .scalar("depthM", r.depthM, bounds::kSpan)
        .scalar("approachM", r.approachM, bounds::kSpan)
        .scalar("approachSeconds", r.approachSeconds, bounds::kDuration)
        .scalar("rampSeconds", r.rampSeconds, bounds::kDuration);
}

void check(const CircleTrajectory& c) {
    TrajectoryCheck("CircleTrajectory")
        .point("centre", c.centre)
        .direction("u", c.u)
        .direction("v", c.v)
        .direction("pressDirection", c.pressDirection)
        .scalar("radiusM", c.radiusM, bounds::kSpan)
        .scalar("|frequencyHz|", std::abs(c.frequencyHz), bounds::kFrequency)
        .scalar("depthM", c.depthM, bounds::kSpan)
        .scalar("approachM", c.approachM, bounds::kSpan)
        .scalar("approachSeconds", c.approachSeconds, bounds::kDuration)
        .scalar("rampSeconds", c.rampSeconds, bounds::kDuration);
}

void check(const SinusoidTrajectory& s) {
    TrajectoryCheck("SinusoidTrajectory")
        .point("start", s.start)
        .direction("direction", s.direction)
        .scalar("amplitudeM", s.amplitudeM, bounds::kSpan)
        .scalar("|frequencyHz|", std::abs(s.frequencyHz), bounds::kFrequency)
        .scalar("growSeconds", s.growSeconds, bounds::kDuration);
}

}  // namespace

void validateTrajectory(const Trajectory& trajectory) {
    std::visit([](const auto& t) { check(t); }, trajectory);
}

}  // namespace palp::haptics
