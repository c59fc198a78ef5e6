#include "palp/studies/touch_modes.h"

#include <algorithm>
#include <cmath>
#include <numbers>
#include <sstream>
#include <string>

#include "palp/base/error.h"
#include "palp/studies/offline_run.h"
#include "palp/volume/phantom.h"

namespace palp::haptics {

const char* touchModeName(TouchMode mode) noexcept {
    switch (mode) {
        case TouchMode::ContinuousPressure:
            return "continuous-pressure";
        case TouchMode::DiscontinuousPressure:
            return "discontinuous-pressure";
        case TouchMode::LateralSweep:
            return "lateral-sweep";
    }
    return "?";
}

namespace {

bool parseName(std::string_view name, TouchMode& mode) noexcept {
    if (name == "continuous-pressure" || name == "cp") {
        mode = TouchMode::ContinuousPressure;
    } else if (name == "discontinuous-pressure" || name == "dp") {
        mode = TouchMode::DiscontinuousPressure;
    } else if (name == "lateral-sweep" || name == "cl" || name == "sweep") {
        mode = TouchMode::LateralSweep;
    } else {
        return false;
    }
    return true;
}

void requireRange(const char* field, double v, double lo, double hi, const char* unit) {
    if (!(v > lo && v <= hi)) {
        std::ostringstream m;
        m << "touch path " << field << ": expected a value in (" << lo << ", " << hi << "] " << unit
          << ", found " << v;
        throw ValueError(m.str());
    }
}

}  // namespace

bool isTouchModeName(std::string_view name) noexcept {
    TouchMode m{};
    return parseName(name, m);
}

TouchMode parseTouchMode(std::string_view what, std::string_view name) {
    TouchMode m{};
    if (!parseName(name, m)) {
        throw ValueError(std::string(what) +
                         ": expected continuous-pressure, discontinuous-pressure or "
                         "lateral-sweep, found '" +
                         std::string(name) + "'");
    }
    return m;
}

double thesisWeberFraction(TouchMode mode) noexcept {
    switch (mode) {
        case TouchMode::ContinuousPressure:
            return 0.0523;
        case TouchMode::DiscontinuousPressure:
            return 0.1291;
        case TouchMode::LateralSweep:
            return 0.1577;
    }
    return 0.23;
}

int touchBox(TouchMode mode) noexcept {
    switch (mode) {
        case TouchMode::ContinuousPressure:
            return 1;
        case TouchMode::DiscontinuousPressure:
            return 0;
        case TouchMode::LateralSweep:
            return 2;
    }
    return 0;
}

TouchParams touchDefaults(TouchMode mode) noexcept {
    TouchParams p;
    if (mode == TouchMode::LateralSweep) {
        p.depthM = 0.002;
        p.speedMps = 0.05;
    } else {
        p.depthM = 0.003;
        p.speedMps = 0.01;
    }
    return p;
}

TouchPath touchPath(TouchMode mode, const TouchParams& params) {
    const TouchParams d = touchDefaults(mode);
    const double depth = params.depthM > 0 ? params.depthM : d.depthM;
    const double speed = params.speedMps > 0 ? params.speedMps : d.speedMps;
    requireRange("depth", depth * 1e3, 0, 20, "mm");
    requireRange("speed", speed, 0, 1, "m/s");
    if (!(params.holdSeconds >= 0 && params.holdSeconds <= 10)) {
        throw ValueError("touch path hold: expected a value in [0, 10] s, found " +
                         std::to_string(params.holdSeconds));
    }
    const Eigen::Vector3d centre(volume::Phantom::stiffnessBoxCentreX(touchBox(mode)), 0, 0);
    const Eigen::Vector3d press = Eigen::Vector3d::UnitY();
    TouchPath out;
    if (mode == TouchMode::LateralSweep) {
        // Two passes over 30 mm centred on the CL box: its 10 mm transition is crossed in both
        // directions, 10 mm of soft and of hard tissue either side.
        SweepTrajectory s;
        s.centre = centre;
        s.direction = Eigen::Vector3d::UnitX();
        s.pressDirection = press;
        s.lengthM = 0.03;
        s.speedMps = speed;
        s.depthM = depth;
        out.trajectory = s;
        out.seconds = trajectoryDuration(out.trajectory, 2);
        out.pressedFrom = s.approachSeconds;
        return out;
    }
    // A press from 5 mm above the surface (the session's start-up gate opens in the air, as
    // in palp palpate's press), along the normal at the box's centre.
    const double above = 0.005;
    PressTrajectory p;
    p.start = centre - above * press;
    p.direction = press;
    p.depthM = depth + above;
    p.pressSeconds = (depth + above) / speed;
    p.holdSeconds = params.holdSeconds;
    out.trajectory = p;
    out.seconds = trajectoryDuration(out.trajectory);
    out.pressedFrom =
        p.pressSeconds * std::acos(1 - 2 * above / (depth + above)) / std::numbers::pi;
    return out;
}

}  // namespace palp::haptics
