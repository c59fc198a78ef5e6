#pragma once
/// @file
/// Haptic devices: what the servo loop reads (position, velocity, buttons) and writes (force),
/// and the limits of a device class (DeviceSpec) with a table of common ones.

#include <Eigen/Core>
#include <cstdint>
#include <span>
#include <string_view>

namespace palp::haptics {

/// One sample of the device, in the device frame.
struct DeviceState {
    Eigen::Vector3d position{Eigen::Vector3d::Zero()};  ///< end-effector position, m
    Eigen::Vector3d velocity{Eigen::Vector3d::Zero()};  ///< end-effector velocity, m/s
    std::uint32_t buttons = 0;                          ///< bit i set: button i pressed
    double timestampSeconds = 0.0;                      ///< time of the sample, s
    /// The device's count of samples (0 where it keeps none). WatchdogDevice takes a sample as
    /// new when its sequence or its timestamp differs from the last one's.
    std::uint64_t sequence = 0;
};

/// What a device reports about its own samples after read() (Session copies it into every
/// Snapshot). A plain device is always healthy; WatchdogDevice fills it.
struct DeviceHealth {
    bool stale = false;            ///< this tick's read() brought no fresh sample
    double forceScale = 1.0;       ///< factor (0..1) the force must be scaled by this tick
    std::uint64_t staleTicks = 0;  ///< consecutive reads without a fresh sample
    std::uint64_t trips = 0;       ///< times the force reached zero for want of samples
};

/// Axis-aligned workspace box in the device frame, m.
struct WorkspaceBox {
    Eigen::Vector3d min{Eigen::Vector3d::Zero()};  ///< lower corner, m
    Eigen::Vector3d max{Eigen::Vector3d::Zero()};  ///< upper corner, m

    /// Edge lengths, m.
    Eigen::Vector3d size() const noexcept { return max - min; }
    /// True when @p p (m) lies inside the box (boundary included).
    bool contains(const Eigen::Vector3d& p) const noexcept {
        return (p.array() >= min.array()).all() && (p.array() <= max.array()).all();
    }
};

/// Limits of a device class. Rendering must stay within them: the force is clamped to
/// maxForceN, and coupling stiffness and damping are chosen below maxStiffnessNpm and
/// maxDampingNspm.
struct DeviceSpec {
    std::string_view name;             ///< human-readable device class
    double maxForceN = 0.0;            ///< peak force, N
    double maxContinuousForceN = 0.0;  ///< force sustainable indefinitely, N
    double maxStiffnessNpm = 0.0;      ///< highest stable rendered stiffness, N/m
    double maxDampingNspm = 0.0;       ///< highest stable rendered damping, N s/m
    WorkspaceBox workspace;            ///< usable workspace, m, centred on the device origin
};

/// Specs of common device classes (see device.cpp for sources and caveats). Names:
/// "3D Systems Touch", "3D Systems Touch X", "Phantom Premium 1.5", "Force Dimension omega.3",
/// "Novint Falcon".
std::span<const DeviceSpec> deviceSpecs() noexcept;

/// The spec named @p name (exact match), or nullptr when there is none.
const DeviceSpec* findDeviceSpec(std::string_view name) noexcept;

struct CouplingParams;  // coupling.h

/// The one stiffness rule for rendering on a device: lowers @p params.maxStiffness to the
/// smallest of
/// * the device's maxStiffnessNpm (the highest stiffness it renders stably; ignored when <= 0
///   or not finite), and
/// * Colgate's sampled-wall passivity bound k < 2 b / T, kept 10 % inside: 0.9 * 2 b / T, with
///   b the device's maxDampingNspm and T = @p periodSeconds, the servo period in s (ignored
///   when either is <= 0 or not finite),
/// and then baseStiffness to maxStiffness when it is above; in AVCEC mode it then widens the
/// spherical stencil (bundle.sobelAngle) to at least sqrt((maxStiffness - baseStiffness) /
/// (4 limit)) rad (at most 0.75), so that the energy term's force field, whose mean stiffness
/// across a stiffness step dk is dk / (4 delta^2), stays renderable (docs/algorithms.md
/// section 3). With neither limit set nothing changes. Returns whether anything was lowered. At the
/// usual 1 kHz no device of deviceSpecs() is bound by the sampled-wall term (it lies 2.5 to 3.6
/// times above its maxStiffnessNpm); it binds for slow servo rates (periods over about 2.5 ms).
/// Session applies it to every coupling it renders (with its servo period), and so do the C
/// API and `palp palpate` / `palp bench tick`.
/// @par Real-time  noexcept, allocation-free.
bool limitStiffnessToDevice(CouplingParams& params, const DeviceSpec& spec,
                            double periodSeconds) noexcept;

/// A haptic device: the servo loop calls read() then write() once per tick.
///
/// @par Threading
/// read() and write() are called from the servo thread only; an implementation owns its state
/// and needs no locking against other threads.
/// @par Real-time
/// Implementations of read() and write() must be noexcept, allocate nothing, take no lock and
/// return in bounded time. A virtual call per tick is fine (one per millisecond).
class Device {
  public:
    virtual ~Device() = default;

    /// Latest sample of the device.
    virtual DeviceState read() noexcept = 0;

    /// Commands @p forceN (N, device frame) until the next call. The caller has already
    /// clamped it to spec().maxForceN; implementations may clamp again.
    virtual void write(const Eigen::Vector3d& forceN) noexcept = 0;

    /// Limits of this device.
    virtual const DeviceSpec& spec() const noexcept = 0;

    /// The state of the samples after the last read() (default: always healthy). A device
    /// whose forceScale is below 1 expects the force written this tick to be scaled by it
    /// (Session does so before its passivity observer books the force).
    virtual DeviceHealth health() const noexcept { return {}; }
};

}  // namespace palp::haptics
