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

/// What can be wrong in one servo tick, as bits (Snapshot::faultFlags, palp_snapshot.fault_flags,
/// the bridge's ForceMessage flags carry them too). The sample faults are judged by
/// WatchdogDevice (all four) and by Session for every device (non-finite, and out of range
/// against palp's world bound); the force faults by Session. docs/architecture.md, "Faults",
/// lists what the loop does for each and what the host sees.
enum DeviceFault : std::uint32_t {
    kFaultStale = 1u << 0,       ///< no new sample: a repeated one, or the device did not answer
    kFaultNonFinite = 1u << 1,   ///< NaN or infinite position, velocity or time
    kFaultOutOfRange = 1u << 2,  ///< position outside the stated bound (the device's workspace)
    kFaultTooFast = 1u << 3,     ///< a speed or a jump since the last good sample no hand makes
    kFaultForceNonFinite = 1u << 4,  ///< the rendered force was NaN or infinite (last good held)
    kFaultForceJump = 1u << 5,       ///< the force would have jumped (limited to a step per tick)
    /// The servo loop exceeded its overrun budget (ServoConfig): the session renders no force
    /// (ramped to zero) and sheds its work until it is restarted.
    kFaultOverload = 1u << 6,
    /// The servo loop shed work to keep its deadlines (ServoTask::shed: VC coupling instead of
    /// AVC/AVCEC, deformable tissue frozen): the force is still rendered, with less detail,
    /// until the loop restores the work or gives up (kFaultOverload).
    kFaultShed = 1u << 7,
};
/// The sample faults that make a sample unusable (its force is held, then ramped to zero).
inline constexpr std::uint32_t kBadSampleFaults =
    kFaultNonFinite | kFaultOutOfRange | kFaultTooFast;
/// Every DeviceFault bit.
inline constexpr std::uint32_t kAllFaults = kBadSampleFaults | kFaultStale | kFaultForceNonFinite |
                                            kFaultForceJump | kFaultOverload | kFaultShed;

/// What a device reports about its own samples after read() (Session copies it into every
/// Snapshot). A plain device is always healthy; WatchdogDevice fills it.
struct DeviceHealth {
    bool stale = false;            ///< this tick's read() brought no fresh, good sample
    double forceScale = 1.0;       ///< factor (0..1) the force must be scaled by this tick
    std::uint64_t staleTicks = 0;  ///< consecutive reads without a fresh, good sample
    std::uint64_t trips = 0;       ///< times the force reached zero for want of good samples
    /// DeviceFault bits of this read's sample (kFaultStale and kBadSampleFaults only): a sample
    /// with a kBadSampleFaults bit is returned by read() as it came, for the caller to refuse.
    std::uint32_t faults = 0;
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

    /// Called by Session each tick just before write(): the tick's DeviceFault bits (the
    /// device's and the session's) and the factor (0..1) the force about to be written was
    /// scaled by. Default: ignored. A device that tells its far end about faults (UdpDevice's
    /// Force flags) keeps them for the next write().
    virtual void reportFaults(std::uint32_t faults, double forceScale) noexcept {
        static_cast<void>(faults);
        static_cast<void>(forceScale);
    }
};

}  // namespace palp::haptics
