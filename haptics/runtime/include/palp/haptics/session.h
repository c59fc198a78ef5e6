#pragma once
/// @file
/// Session (device + proxy + coupling + passivity + safety + the servo loop, with lock-free
/// snapshots and a command queue): the facade a viewer embeds. The Scene it renders is in
/// scene.h (included here, so includers of session.h keep seeing it).

#include <Eigen/Geometry>
#include <cstdint>
#include <limits>
#include <memory>
#include <optional>

#include "palp/base/spsc_queue.h"
#include "palp/base/triple_buffer.h"
#include "palp/haptics/devices/device.h"
#include "palp/haptics/rendering/coupling.h"
#include "palp/haptics/rendering/proxy.h"
#include "palp/haptics/scene.h"
#include "palp/haptics/servo_loop.h"
#include "palp/haptics/tissue/deformable.h"
#include "palp/haptics/tissue/surface_frame.h"
#include "palp/kernels/embree_scene.h"
#include "palp/kernels/triangle_mesh.h"
#include "palp/kernels/volume_ray.h"
#include "palp/volume/volume.h"

namespace palp::haptics {

/// Device frame -> world: world = offset + scale * rotation * device.
struct WorkspaceTransform {
    double scale = 1;
    Eigen::Matrix3d rotation{Eigen::Matrix3d::Identity()};
    Eigen::Vector3d offset{Eigen::Vector3d::Zero()};
};

/// How a session treats the faults it finds itself, on any device: a sample it refuses
/// (non-finite, or beyond palp's world bound) and a force that is not finite or would jump
/// (DeviceFault). Each such tick counts as missing for a FaultRamp with these times, as a
/// WatchdogDevice counts missing samples (docs/architecture.md, "Faults").
struct FaultParams {
    double graceSeconds = 2e-3;     ///< s: the force stays whole this long (0 <= g < timeout)
    double timeoutSeconds = 10e-3;  ///< s: zero force after this long (0 < t <= 10)
    double resumeSeconds = 50e-3;   ///< s: time for the force to climb back (0..10)
    /// Largest change of the force (before the ramps' scale) in one tick, N; a larger change is
    /// limited to it (kFaultForceJump), except a drop to exactly zero (a cut is always allowed).
    /// 0: half the device's maxForceN (a step no stable rendering makes: on a 3D Systems Touch
    /// X at its highest stiffness a 3.9 N step in 1 ms needs a hand at 2.7 m/s).
    double maxForceStepN = 0;
};

/// Re-contact after the tissue sprang back past a free probe (deformable scenes only). On soft
/// tissue the contact can be lost for a tick or two while the tissue rings; released, the dent
/// springs back millimetres in one FEM step, past the probe, and the proxy is put back on the
/// surface with the probe 1.5-5 mm inside: the coupling spring's k D would kick the hand (on
/// the head CT up to the device's 3.3 N, ~5 ticks in 8 s). For `seconds` after such a
/// re-contact the force's magnitude may rise by at most `riseNps` (a fall is never slowed),
/// while the dent forms again under the rising load; past the window the limit holds until the
/// coupling's force is within it, so the window's end is no step (docs/algorithms.md, 10).
struct RecontactParams {
    double seconds = 15e-3;  ///< s: the window after a re-contact (0: no limit; 0..1)
    double riseNps = 100;    ///< N/s: the magnitude's largest rise in the window (> 0)
};

struct SessionParams {
    ProxyParams proxy;
    CouplingParams coupling;
    WorkspaceTransform workspace;
    bool passivityControl = false;   ///< the observer always runs; this adds the controller
    double startupThresholdN = 0.3;  ///< force below which a start-up tick counts as quiet
    std::uint32_t startupQuietTicks = 50;
    double crossFadeSeconds = 0.2;  ///< parameter changes fade over this long
    ServoConfig servo;
    /// Snapshots kept for popTrace() (every tick's, in order; rounded up to a power of two;
    /// 0: no trace). When the reader falls behind, new snapshots are dropped and counted.
    std::uint32_t traceCapacity = 0;
    FaultParams faults;         ///< the session's own fault ramp and force-step limit
    RecontactParams recontact;  ///< the force's rise after the tissue springs back past the probe
};

/// @throw palp::ValueError naming the field (through the parts' validators too).
void validateSessionParams(const SessionParams& params);

/// Ticks so far with each fault (DeviceFault), counted by the session.
struct FaultCounts {
    std::uint64_t stale = 0;           ///< kFaultStale: no new sample
    std::uint64_t nonFinite = 0;       ///< kFaultNonFinite samples
    std::uint64_t outOfRange = 0;      ///< kFaultOutOfRange samples
    std::uint64_t tooFast = 0;         ///< kFaultTooFast samples
    std::uint64_t forceNonFinite = 0;  ///< kFaultForceNonFinite ticks
    std::uint64_t forceJump = 0;       ///< kFaultForceJump ticks
    std::uint64_t overload = 0;        ///< kFaultOverload ticks
    std::uint64_t shed = 0;            ///< kFaultShed ticks (work shed, force still rendered)
};

/// One tick's state, published lock-free for viewers and traces. Plain data.
struct Snapshot {
    std::uint64_t tick = 0;
    double timeSeconds = 0;
    Eigen::Vector3d probe{Eigen::Vector3d::Zero()};  ///< world, m
    Eigen::Vector3d proxy{Eigen::Vector3d::Zero()};  ///< world, m
    Eigen::Vector3d force{Eigen::Vector3d::Zero()};  ///< sent to the device (world frame), N
    /// The coupling's force on the probe (damping and AVCEC's spherical term included) before
    /// guard, clamp, start-up gate and passivity controller, world frame, N.
    Eigen::Vector3d couplingForce{Eigen::Vector3d::Zero()};
    Eigen::Vector3d energyForce{Eigen::Vector3d::Zero()};  ///< AVCEC spherical term, N
    Eigen::Vector3d proxyForce{Eigen::Vector3d::Zero()};   ///< AVCEC surface term, N
    double stiffness = 0, rayLength = 0, distance = 0, couplingEnergy = 0;
    double observerEnergy = 0;  ///< passivity W, J
    double addedDamping = 0;    ///< controller alpha, N s/m
    double passivityCut = 0;    ///< controller: force cut along the velocity beyond alpha, N
    int contactCount = 0;
    int rays = 0;
    bool sticking = false, gateOpen = false, faulted = false, clamped = false;
    CouplingMode mode = CouplingMode::VC;
    /// The coupling in force (the newest one during a fade) asked for a maxStiffness or
    /// baseStiffness above the device's limit (limitStiffnessToDevice) and renders the lowered
    /// one.
    bool stiffnessLimited = false;
    bool fading = false;    ///< a SetCoupling cross-fade is running
    double fadeWeight = 1;  ///< weight of the newest coupling params (0..1)
    /// Ticks so far whose force was non-finite or whose sample was refused (the last good force
    /// held; `faulted` marks such a tick).
    std::uint64_t faults = 0;
    /// The device's watchdog (WatchdogDevice; always false / 0 for other devices): this tick
    /// brought no fresh, good sample (deviceStale); outages so far whose force reached zero
    /// (watchdogTrips). deviceForceScale: the factor the force was scaled by this tick (0:
    /// cut), the device watchdog's and the session's fault ramp (FaultParams), the smaller.
    bool deviceStale = false;
    double deviceForceScale = 1;
    std::uint64_t watchdogTrips = 0;
    /// This tick's DeviceFault bits: the device's (stale, a bad sample) and the session's (a
    /// sample it refused, a non-finite force, a force step limited). Set on the very tick the
    /// fault happens.
    std::uint32_t faultFlags = 0;
    FaultCounts faultCounts;       ///< ticks so far with each fault
    std::uint64_t faultTrips = 0;  ///< outages of the session's fault ramp that reached zero
    // Deformable scenes only (zero / -1 otherwise).
    /// Mean force on the tissue over this tick's FEM step, N: the coupling spring's, solved with
    /// the tissue (-force in a steady contact; it leads -force by the spring's change within the
    /// tick while the probe moves).
    Eigen::Vector3d tissueForce{Eigen::Vector3d::Zero()};
    int contactNode = -1;        ///< FEM node with the largest share of the load, -1: none
    double maxDisplacement = 0;  ///< largest surface node displacement after the step, m
    unsigned femFlags =
        0;  ///< fem::StepFlag bits, DeformableBody::kRefitFailed / kSurfaceOutsideBounds
};

/// A parameter change sent to a running session; applied at a tick boundary (coupling changes
/// cross-faded).
struct Command {
    enum class Kind : std::uint8_t {
        SetCoupling,
        SetProxy,
        SetPassivityControl,
        ResetObserver,
        /// coupling, proxy and flag together: one queue slot, applied at one tick boundary, so
        /// a full queue refuses all three and none is applied alone (the coupling part then
        /// follows SetCoupling's cross-fade rules).
        SetAll,
    };
    Kind kind = Kind::SetCoupling;
    CouplingParams coupling;  ///< SetCoupling, SetAll (validated by send())
    ProxyParams proxy;        ///< SetProxy, SetAll
    bool flag = false;        ///< SetPassivityControl, SetAll: the controller on or off
    /// Set by send() (ignored on input): the coupling's stiffness was lowered to the device's
    /// limit (limitStiffnessToDevice); shown as Snapshot::stiffnessLimited.
    bool stiffnessLimited = false;
};

/// Device + proxy + coupling + passivity + safety, ticked by a ServoLoop (start()) or by the
/// caller (step(), for offline runs as fast as possible).
///
/// One tick: read the device; probe = workspace(device position), probe velocity = scale *
/// rotation * device velocity; drain the command queue; proxy.update(probe, last tick's AVCEC
/// proxy force minus its spherical term, last tick's k (baseStiffness before any), T, last
/// tick's step stiffness); coupling.compute(); in AVCEC (no fade) a proxy move that raises
/// E = 1/2 k D^2 at the new probe is undone and the coupling computed again (docs/algorithms.md
/// section 3); during a
/// SetCoupling cross-fade the old and the new coupling both run and force, proxy force, k and
/// energy are blended linearly over crossFadeSeconds (a SetCoupling that arrives during a fade
/// waits for it to end; the newest waiting one wins); ForceGuard (a non-finite force or device
/// sample holds the last good force and flags the tick); clampForce to the device's maxForceN;
/// StartupGate; the force-step limit (FaultParams::maxForceStepN); the smaller of the device's
/// Device::health().forceScale (a WatchdogDevice's cut, 1 otherwise) and the session's own
/// fault ramp (FaultParams: ticks with a refused sample, a non-finite force or a limited step
/// count as missing);
/// the passivity observer (and controller when enabled) books that force, the one
/// actually sent, against the device velocity in the device's scale, so W is the energy
/// exchanged with the hand (the controller's damping is added and clamped again); the force is
/// rotated back (F_device = R^T F_world, not scaled) and written;
/// the tick's faults go to Device::reportFaults() and the force is written;
/// the Snapshot is published (latest()), queued for popTrace() and the bundle for latestRays().
/// A sample is refused (no proxy move, no ray; the last good force is held, then ramped) when
/// it is not finite, when a coordinate of the probe lies beyond 10 km or a velocity component
/// beyond 10 km/s (palp's own bound, for any device), or when the device's health() marks it
/// bad (a WatchdogDevice's workspace and speed checks).
/// A probe that starts inside a closed surface (ray parity) is not trapped by it: the proxy
/// follows the probe freely until the probe is outside.
///
/// Deformable scene (Scene::setDeformable): the proxy updates against the body's deformed
/// surface, and AVC/AVCEC rays start from the proxy there (against the scene's hard meshes or
/// volume and, with the Mesh source, the body's embedded meshes as deformed); after the chain
/// above, the tissue is coupled to the probe at the proxy while the proxy is in contact
/// (DeformableBody::coupleContact: a spring of the tick's coupling stiffness pulling with -F at
/// the step's start, solved with the tissue inside the FEM substeps; nothing otherwise); the
/// FEM steps by T and the surface is refitted; a proxy in
/// contact is then carried with the surface point under it (same triangle, barycentric
/// coordinates and offset), so a surface that springs back pushes the proxy out instead of
/// swallowing it. The carry resets the proxy's velocity estimate (only the coupling damping b
/// sees it). A free proxy (no contact) that a fast-moving surface overtakes is pushed back out
/// along the shortest axis-aligned exit.
///
/// Device stability limit: every coupling the session renders (the one in SessionParams and
/// each SetCoupling / SetAll) goes through limitStiffnessToDevice() (device.h) with the servo
/// period, so k never exceeds the device's maxStiffnessNpm nor the sampled-wall bound
/// whatever the caller asked for. The session clamps rather than
/// refuses (as `palp palpate` does), so one set of parameters works on every device class;
/// the clamp is reported by stiffnessLimited(), params() (the lowered values) and every
/// Snapshot's stiffnessLimited.
///
/// Time: Snapshot::timeSeconds never goes backwards. Offline steps advance it by T; a
/// real-time run continues from the last tick's time + T on the servo loop's nominal clock
/// (which skips the deadlines of overrun ticks); step() after a run continues from the run's
/// last tick + T, and so on across any sequence of start/stop/step.
///
/// @par Threading  start/stop/step from one controlling thread; latest(), latestRays() and
///      latestSurface() from one viewer thread; popTrace() from one trace reader thread (may
///      be the viewer); send() from one producer thread. The servo thread owns everything else.
/// @par Real-time  A tick (step() or the servo thread's) is noexcept and allocation-free (on a
///      deformable scene except Embree's refit, which calls operator new a few times).
/// Live, a deformable scene's surface goes to the viewer every this many ticks.
inline constexpr std::uint64_t kSurfaceFrameTicks = 8;

class Session final : public ServoTask {
  public:
    /// @p scene must be committed; @p device must outlive the session.
    /// @throw palp::ValueError for invalid parameters.
    Session(std::shared_ptr<const Scene> scene, Device& device, const SessionParams& params);
    ~Session() override;

    /// Runs on a ServoLoop; closes the start-up gate again first (no kick on a restart with
    /// the hand inside an object). @throw palp::Error (see ServoLoop::start)
    void start();
    void stop() noexcept;  ///< idempotent
    bool running() const noexcept;
    /// One tick on the calling thread; time advances by T per step. While the servo thread
    /// runs it does nothing and returns the last step()'s snapshot.
    const Snapshot& step() noexcept;
    /// Controlling thread, while stopped: the newest tick's snapshot (the servo thread's last
    /// after a run, step()'s after a step; a default Snapshot before any tick). While the servo
    /// thread runs: the last step()'s.
    const Snapshot& newest() const noexcept;

    /// Viewer: the newest published snapshot.
    const Snapshot& latest() noexcept;
    /// Producer: queue a command; false when the queue is full (nothing queued). A coupling
    /// (SetCoupling, SetAll) is first limited to the device (limitStiffnessToDevice), and its
    /// first-hit march gets the session's kernels::HitField for its threshold: built here the
    /// first time a threshold is used (about 35 ms and 2 MiB on a 0.5 mm head CT; the
    /// session keeps up to 8, later thresholds march without one, same results to rounding).
    /// @throw palp::ValueError for invalid parameters (checked here, off the servo thread;
    /// nothing is queued).
    bool send(const Command& command);

    /// Trace reader (one thread): the oldest unread snapshot of the trace ring; false when
    /// none is queued (or SessionParams::traceCapacity is 0). Never blocks the servo thread.
    bool popTrace(Snapshot& out) noexcept;
    /// Snapshots the servo thread could not queue because the trace ring was full.
    std::uint64_t traceDropped() const noexcept;
    /// Viewer (the thread that calls latest()): the newest tick's ray bundle (origins,
    /// directions, L_max; count 0 in VC or without contact distance), for drawing.
    const kernels::RayBundle& latestRays() noexcept;
    /// Viewer (the thread that calls latest()): the newest published deformed surface (vertex
    /// positions in the order of DeformableModel::surface().vertices, whose triangles are
    /// fixed; its tick is the Snapshot's it was published with); nullptr on a rigid scene.
    /// Published after every step() and, on the servo thread, every kSurfaceFrameTicks-th
    /// tick (125 frames a second at 1 kHz: more than a display draws). Frames are
    /// preallocated: publishing one costs the servo thread O(#V), no allocation.
    const SurfaceFrame* latestSurface() noexcept;

    ServoStats stats() const noexcept;
    const RealtimeStatus& realtime() const noexcept;
    /// The parameters given at construction, with the coupling limited to the device.
    const SessionParams& params() const noexcept { return mParams; }
    /// Whether construction lowered the coupling's stiffness to the device's limit.
    bool stiffnessLimited() const noexcept { return mStiffnessLimited; }
    const DeviceSpec& deviceSpec() const noexcept;
    /// The session's deformable body (nullptr for a rigid scene). Read it only while the
    /// session is stopped (the servo thread owns it while running).
    const DeformableBody* deformable() const noexcept;
    /// Producer thread: first-hit fields built so far (one per threshold used; 0 without a
    /// volume).
    std::size_t hitFieldCount() const noexcept;

    void tick(const TickInfo& info) noexcept override;
    /// The loop's first window over its overrun budget (ServoLoop; on the servo thread, or
    /// between offline steps): from the next tick the session renders with less work: an AVC
    /// or AVCEC coupling gives way to VC with the same parameters (no ray bundle; cross-faded
    /// as any coupling change), and deformable tissue is frozen in its current shape (no FEM
    /// step; the proxy stays on the frozen surface). kFaultShed on every tick until restore()
    /// or the next start(). A coupling set meanwhile is kept and applied (as VC) then. Returns
    /// false when there is nothing to shed (VC on a rigid scene) or the loop is overloaded.
    bool shed() noexcept override;
    /// Takes back what shed() dropped: the coupling asked for last (cross-faded) and the FEM.
    void restore() noexcept override;
    /// The servo loop exceeded its overrun budget (ServoConfig::overrunWindowSeconds; it has
    /// dropped SCHED_FIFO): from the next tick until the next start() the session renders no
    /// force (held, then ramped to zero as for a refused sample; kFaultOverload on every tick)
    /// and sheds its work (no proxy, no rays, no FEM step): the tick only reads the device,
    /// writes the ramped force and publishes. stats().overloaded says when.
    void overloaded() noexcept override;

  private:
    struct Impl;
    std::unique_ptr<Impl> mImpl;
    SessionParams mParams;
    bool mStiffnessLimited = false;
};

}  // namespace palp::haptics
