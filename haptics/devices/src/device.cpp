#include "palp/haptics/devices/device.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>

#include "palp/haptics/rendering/coupling.h"

namespace palp::haptics {
namespace {

// Workspace box of width w (x), height h (y) and depth d (z), mm, centred on the origin.
WorkspaceBox boxMm(double w, double h, double d) {
    const Eigen::Vector3d half = 0.5e-3 * Eigen::Vector3d(w, h, d);
    return WorkspaceBox{-half, half};
}

// Nominal vendor figures from the product data sheets; individual units, firmware and
// calibration differ, so treat them as upper bounds to stay below, not as measurements.
// Where the vendor publishes a stiffness per axis, the lowest axis is used. Vendors do not
// publish a maximum rendered damping; those values are conservative palp defaults (marked).
const std::array<DeviceSpec, 5> kSpecs = {{
    // 3D Systems Touch (formerly Phantom Omni): 3.3 N peak, 0.88 N continuous, stiffness
    // x 1.26, y 2.31, z 1.02 N/mm, workspace 160 x 120 x 70 mm.
    {"3D Systems Touch", 3.3, 0.88, 1020.0, 2.0 /* palp default */, boxMm(160, 120, 70)},
    // 3D Systems Touch X (formerly Phantom Desktop): 7.9 N peak, 1.75 N continuous, stiffness
    // x 1.86, y 2.35, z 1.48 N/mm, workspace 160 x 120 x 120 mm.
    {"3D Systems Touch X", 7.9, 1.75, 1480.0, 3.0 /* palp default */, boxMm(160, 120, 120)},
    // Phantom Premium 1.5: 8.5 N peak, 1.4 N continuous, 3.5 N/mm, workspace 381 x 267 x 191 mm.
    {"Phantom Premium 1.5", 8.5, 1.4, 3500.0, 5.0 /* palp default */, boxMm(381, 267, 191)},
    // Force Dimension omega.3: 12 N continuous, 14.5 N/mm, workspace a cylinder of 160 mm
    // diameter and 110 mm length (its bounding box here; the axis is x).
    {"Force Dimension omega.3", 12.0, 12.0, 14500.0, 20.0 /* palp default */, boxMm(110, 160, 160)},
    // Novint Falcon: more than 2 lbf (8.9 N), workspace 4 x 4 x 4 in (101.6 mm). No stiffness
    // figure is published; 1000 N/m is a conservative palp default, and so is the continuous
    // force.
    {"Novint Falcon", 8.9, 2.0 /* palp default */, 1000.0 /* palp default */,
     2.0 /* palp default */, boxMm(101.6, 101.6, 101.6)},
}};

}  // namespace

std::span<const DeviceSpec> deviceSpecs() noexcept { return kSpecs; }

const DeviceSpec* findDeviceSpec(std::string_view name) noexcept {
    for (const DeviceSpec& s : kSpecs) {
        if (s.name == name) return &s;
    }
    return nullptr;
}

namespace {
/// The widest spherical stencil limitStiffnessToDevice() asks for, rad.
constexpr double kMaxRenderableAngle = 0.75;
}  // namespace

bool limitStiffnessToDevice(CouplingParams& params, const DeviceSpec& spec,
                            double periodSeconds) noexcept {
    auto usable = [](double v) { return v > 0 && std::isfinite(v); };
    double limit = std::numeric_limits<double>::infinity();
    if (usable(spec.maxStiffnessNpm)) limit = spec.maxStiffnessNpm;
    if (usable(spec.maxDampingNspm) && usable(periodSeconds)) {
        // Colgate's sampled-wall bound b > k T / 2: stay 10 % inside it.
        limit = std::min(limit, 0.9 * 2.0 * spec.maxDampingNspm / periodSeconds);
    }
    if (!(limit < std::numeric_limits<double>::infinity())) return false;
    bool lowered = false;
    if (!(params.maxStiffness <= limit)) {
        params.maxStiffness = limit;
        lowered = true;
    }
    if (!(params.baseStiffness <= params.maxStiffness)) {
        params.baseStiffness = params.maxStiffness;
        lowered = true;
    }
    // AVCEC's spherical term: a stiffness step dk seen across the stencil gives the hand a
    // force field of mean stiffness dk / (4 delta^2); keep it within the device's limit.
    const double contrast = params.maxStiffness - params.baseStiffness;
    if (params.mode == CouplingMode::AVCEC && contrast > 0) {
        const double angle = std::min(std::sqrt(contrast / (4.0 * limit)), kMaxRenderableAngle);
        if (!(params.bundle.sobelAngle >= angle)) {
            params.bundle.sobelAngle = angle;
            lowered = true;
        }
    }
    return lowered;
}

}  // namespace palp::haptics
