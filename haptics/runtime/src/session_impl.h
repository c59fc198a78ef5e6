#pragma once
// Internal to palp_haptics: Session's state (Session::Impl), shared by session.cpp (set-up and
// the controlling, producer, viewer and trace-reader threads' side: start/stop, step, latest,
// popTrace, send) and session_tick.cpp (the servo thread's tick, its stages and the command
// drain). Which thread owns which member is written on the members.

#include <array>
#include <atomic>
#include <cmath>
#include <cstdint>
#include <limits>
#include <map>
#include <memory>
#include <utility>

#include "palp/base/nothrow_slot.h"
#include "palp/base/spsc_queue.h"
#include "palp/haptics/devices/fault_ramp.h"
#include "palp/haptics/rendering/passivity.h"
#include "palp/haptics/rendering/safety.h"
#include "palp/haptics/session.h"
#include "palp/haptics/tissue/surface_frame.h"

namespace palp::haptics {
namespace detail {

/// Most first-hit thresholds a session keeps a HitField for (a few MiB to tens of MiB each on a
/// CT); a coupling with a further threshold marches without one.
inline constexpr std::size_t kMaxHitFields = 8;

/// The session's first-hit fields, one per threshold, built off the servo thread (set-up and
/// Session::send(), the producer thread) and kept until the session ends, so that every
/// pointer a queued or running coupling holds stays valid; the servo thread only reads them.
struct HitFields {
    std::map<float, std::unique_ptr<kernels::HitField>> byThreshold;
    /// The field for @p threshold, built on first use; null without a volume or past the cap.
    const kernels::HitField* get(const Scene& scene, float threshold) {
        const kernels::VolumeView* view = scene.volumeView();
        if (view == nullptr || view->empty()) return nullptr;
        if (auto it = byThreshold.find(threshold); it != byThreshold.end()) return it->second.get();
        if (byThreshold.size() >= kMaxHitFields) return nullptr;
        auto field = std::make_unique<kernels::HitField>(*view, threshold);
        const kernels::HitField* out = field.get();
        byThreshold.emplace(threshold, std::move(field));
        return out;
    }
};

/// @p p with @p field for its first-hit threshold.
inline CouplingParams withField(CouplingParams p, const kernels::HitField* field) noexcept {
    p.firstHit.field = field;
    return p;
}

// A deformable body's scene when it holds embedded (moving) hard meshes, else nullptr.
inline const kernels::EmbreeScene* movingMeshes(const DeformableBody* body) noexcept {
    return body != nullptr && !body->model().embedded().empty() ? &body->surfaces() : nullptr;
}

}  // namespace detail

struct Session::Impl {
    Impl(std::shared_ptr<const Scene> sceneIn, Device& deviceIn, const SessionParams& p,
         bool stiffnessLimited)
        : scene(std::move(sceneIn)),
          device(deviceIn),
          spec(deviceIn.spec()),
          workspace(p.workspace),
          period(p.servo.periodSeconds),
          body(scene->deformable() ? std::make_unique<DeformableBody>(scene->deformable())
                                   : nullptr),
          proxy(body ? body->surfaces() : scene->surfaces(), p.proxy),
          couplings{Coupling(scene->volumeView(), &scene->hardMeshes(),
                             detail::withField(p.coupling,
                                               fields.get(*scene, p.coupling.firstHit.threshold)),
                             detail::movingMeshes(body.get())),
                    Coupling(scene->volumeView(), &scene->hardMeshes(),
                             detail::withField(p.coupling,
                                               fields.get(*scene, p.coupling.firstHit.threshold)),
                             detail::movingMeshes(body.get()))},
          fadeTicks(static_cast<std::uint32_t>(std::lround(p.crossFadeSeconds / period))),
          passivity(period, p.passivityControl,
                    spec.maxDampingNspm > 0 ? spec.maxDampingNspm
                                            : std::numeric_limits<double>::infinity(),
                    spec.maxForceN > 0 ? spec.maxForceN : std::numeric_limits<double>::infinity()),
          gate(p.startupThresholdN, p.startupQuietTicks),
          faultRamp(p.faults.graceSeconds, p.faults.timeoutSeconds, p.faults.resumeSeconds,
                    p.servo.periodSeconds),
          maxForceStep(p.faults.maxForceStepN > 0 ? p.faults.maxForceStepN
                                                  : 0.5 * deviceIn.spec().maxForceN),
          recontactTicks(
              static_cast<std::uint32_t>(std::lround(p.recontact.seconds / p.servo.periodSeconds))),
          recontactRise(p.recontact.riseNps * p.servo.periodSeconds),
          trace(p.traceCapacity),
          loop(p.servo) {
        limited.fill(stiffnessLimited);
        if (body) {
            SurfaceFrame frame(body->model().surface().vertices.size());
            frame.fill(*body, 0, 0.0);  // the rest surface until the first tick
            surfaces = std::make_unique<TripleBuffer<NothrowSlot<SurfaceFrame>>>(
                NothrowSlot<SurfaceFrame>(frame));
        }
        // Volume rays on deformable tissue sample the scan where the tissue was at rest.
        if (body)
            for (Coupling& c : couplings) c.setDeformation(body.get());
    }

    /// One tick's device sample in world terms (stage 1 of a tick).
    struct HandSample {
        /// The device velocity in world orientation but device scale: what the passivity
        /// observer pairs with the force (F_world . (R v_device) = F_device . v_device, the
        /// power that actually flows into the user's hand), m/s.
        Eigen::Vector3d handVelocity;
        Eigen::Vector3d probe;          ///< world, m
        Eigen::Vector3d probeVelocity;  ///< world, m/s
        /// kBadSampleFaults bits the session found itself (non-finite, beyond its bound)
        std::uint32_t faults = 0;
        bool ok = false;  ///< usable: no bad-sample bit, the session's or the device's
    };
    /// What the force chain sends (stage 3 of a tick).
    struct SentForce {
        Eigen::Vector3d force;     ///< world frame, N; always finite
        bool faulted = false;      ///< the coupling's force (or the sample) was not finite
        bool clamped = false;      ///< maxForceN cut the force (before or after the damping)
        std::uint32_t faults = 0;  ///< kFaultForceNonFinite, kFaultForceJump
        double scale = 1;          ///< the factor applied: device's and session's ramp, smaller
    };

    // The tick's stages, in order; all run on the servo thread (or step()'s), noexcept,
    // allocation-free and lock-free, in bounded time.
    void tick(double timeSeconds) noexcept;
    HandSample deviceToWorld(const DeviceState& state) const noexcept;
    void drainCommands() noexcept;
    const ProxyState& moveProxy(const Eigen::Vector3d& probe) noexcept;
    void coupleWithFade(const ProxyState& ps, const HandSample& hand) noexcept;
    bool rejectUphillMove(const ProxyState& before, const ProxyState& after,
                          const HandSample& hand) noexcept;
    SentForce forceChain(const Eigen::Vector3d& couplingForce, const Eigen::Vector3d& handVelocity,
                         double deviceScale, bool sampleRefused) noexcept;
    Eigen::Vector3d limitStep(const Eigen::Vector3d& force, SentForce& out) noexcept;
    void countFaults(std::uint32_t faults) noexcept;
    Eigen::Vector3d worldToDevice(const Eigen::Vector3d& force) const noexcept {
        return workspace.rotation.transpose() * force;  // rotated back, not scaled
    }
    bool contactTissue(const ProxyState& ps, const Eigen::Vector3d& sent,
                       Eigen::Vector3d& tissueForce) noexcept;
    void publish(double timeSeconds, const ProxyState& ps, const SentForce& sent,
                 const Eigen::Vector3d& tissueForce) noexcept;
    void followSurface(bool anchored) noexcept;

    void setCoupling(const CouplingParams& params, bool stiffnessLimited) noexcept;
    // A coupling asked for (a command): VC in its place while shedding (the rest kept for
    // restore()), as asked otherwise.
    void requestCoupling(const CouplingParams& params, bool stiffnessLimited) noexcept;
    bool shed() noexcept;
    void restore() noexcept;
    void startFade(const CouplingParams& params, bool stiffnessLimited) noexcept;
    // The time of the tick after the newest one (0 before any), s.
    double nextTime() const noexcept { return ticks == 0 ? 0.0 : current.timeSeconds + period; }

    std::shared_ptr<const Scene> scene;
    // First-hit fields by threshold (set-up and send(); see HitFields). Declared before the
    // couplings, which are built with the starting threshold's.
    detail::HitFields fields;
    Device& device;
    DeviceSpec spec;
    WorkspaceTransform workspace;
    double period;

    // Servo-thread state.
    std::unique_ptr<DeformableBody> body;  // deformable scenes only; before proxy (it traces it)
    Proxy proxy;
    std::array<Coupling, 2> couplings;  // [active] the newest params, [1 - active] fading out
    std::array<bool, 2> limited{};      // couplings[i]'s stiffness was lowered to the device's
    std::array<CouplingOutput, 2> outputs;
    CouplingOutput blended;
    int active = 0;
    bool fading = false;
    CrossFade fade{1.0};
    std::uint32_t fadeTicks;
    bool hasPending = false;  // a SetCoupling that arrived during a fade (the newest wins)
    CouplingParams pending;
    bool pendingLimited = false;
    PassivityController passivity;
    ForceGuard guard;
    StartupGate gate;
    FaultRamp faultRamp;  // the session's own: refused samples, bad forces (FaultParams)
    double maxForceStep;  // N per tick (FaultParams::maxForceStepN or half maxForceN)
    Eigen::Vector3d lastStepped{Eigen::Vector3d::Zero()};  // the force after the step limit
    FaultCounts faultCounts;
    DeviceHealth health;        // the device's report on this tick's sample
    bool started = false;       // the first good sample has been seen
    bool overloaded = false;    // the loop's overrun budget was exceeded (until start())
    bool shedding = false;      // the loop shed work (Session::shed) until restore() or start()
    bool shedCoupling = false;  // shedding put VC in place of wanted (an AVC/AVCEC coupling)
    CouplingParams wanted;      // the coupling to restore (the newest asked for)
    bool wantedLimited = false;
    bool freeProxy = false;  // the probe started inside: the proxy follows it until outside
    // Re-contact after the tissue sprang back past a free probe (followSurface, RecontactParams):
    // the window's length, the largest rise a tick (N), the ticks left in the window, the last
    // magnitude let through, and whether the limit is on (the window, then until the coupling's
    // force is within the limit).
    std::uint32_t recontactTicks;
    double recontactRise;
    std::uint32_t recontactLeft = 0;
    double recontactLast = 0;
    bool recontactLimiting = false;
    Eigen::Vector3d lastProxyForce{Eigen::Vector3d::Zero()};
    double lastStiffness = 0;
    double lastStepStiffness = 0;
    Eigen::Vector3d lastProbe{Eigen::Vector3d::Zero()};
    Eigen::Vector3d lastProbeVelocity{Eigen::Vector3d::Zero()};  // of the last good sample
    std::uint64_t ticks = 0;
    Snapshot current;
    Command command;  // scratch for draining

    // Cross-thread exchanges.
    SpscQueue<Command, 64> commands;                     // producer -> servo
    TripleBuffer<NothrowSlot<Snapshot>> snapshots;       // servo -> viewer
    TripleBuffer<NothrowSlot<kernels::RayBundle>> rays;  // servo -> viewer
    // servo -> viewer: the deformed surface (deformable scenes only), frames preallocated.
    std::unique_ptr<TripleBuffer<NothrowSlot<SurfaceFrame>>> surfaces;
    SpscRing<NothrowSlot<Snapshot>> trace;       // servo -> trace reader
    NothrowSlot<Snapshot> traceScratch;          // the servo thread's, for trace
    std::atomic<std::uint64_t> traceDropped{0};  // written by the servo thread only

    // Controlling thread.
    ServoLoop loop;
    Snapshot stepSnapshot;  // what step() returns (written only by step())
    double timeBase = 0;    // time of the first tick of the current run, s
    // Offline steps: step n since the last start()/construction runs at stepOrigin + n T
    // (multiplied, not summed, so long offline runs keep exact tick times).
    double stepOrigin = 0;
    std::uint64_t stepIndex = 0;
    bool resyncSteps = false;  // a real-time run happened since: move stepOrigin past it
    bool offlineStep = false;  // the tick running is step()'s (publishes the surface always)
};

}  // namespace palp::haptics
