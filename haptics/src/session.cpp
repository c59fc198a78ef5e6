#include "palp/haptics/session.h"

#include <array>
#include <atomic>
#include <cmath>
#include <limits>
#include <map>
#include <string>

#include "palp/base/bounds.h"
#include "palp/base/error.h"
#include "palp/base/nothrow_slot.h"
#include "palp/base/spsc_queue.h"
#include "palp/base/validate.h"
#include "palp/haptics/passivity.h"
#include "palp/haptics/safety.h"
#include "palp/haptics/surface_frame.h"

namespace palp::haptics {
namespace {

/// Largest |coordinate| (m) of a probe sample taken as real: a thousand times palp's world
/// bound (bounds::kPosition), far inside what Embree's rays accept.
constexpr double kMaxProbeCoordinate = 1e4;
/// Largest |velocity component| (m/s) of a probe sample taken as real.
constexpr double kMaxProbeSpeed = 1e4;

constexpr std::uint32_t kMaxTraceCapacity = 1u << 24;  // 16 M snapshots (a few GB): a typo guard

// The blend of the fading-out (a) and the new (b) coupling outputs with weight w of b.
void blend(const CouplingOutput& a, const CouplingOutput& b, double w,
           CouplingOutput& out) noexcept {
    const double u = 1.0 - w;
    out.force = u * a.force + w * b.force;
    out.proxyForce = u * a.proxyForce + w * b.proxyForce;
    out.energyForce = u * a.energyForce + w * b.energyForce;
    out.stiffness = u * a.stiffness + w * b.stiffness;
    out.stepStiffness = u * a.stepStiffness + w * b.stepStiffness;
    out.energy = u * a.energy + w * b.energy;
    out.rayLength = b.rayLength;
    out.distance = b.distance;
    out.sphere = b.sphere;
    out.surface = b.surface;
    out.rays = a.rays + b.rays;
}

// Whether @p p lies inside the closed surfaces of @p scene (geometries of @p mask): the parity
// of the crossings along three rays in directions no axis-aligned face is parallel to, by
// majority (a ray through a shared edge can miscount). Bounded: at most 3 x 65 ray queries.
bool insideSurfaces(const kernels::EmbreeScene& scene, unsigned mask,
                    const Eigen::Vector3d& p) noexcept {
    if (scene.empty() || !scene.committed() || !p.allFinite()) return false;
    static constexpr std::array<std::array<float, 3>, 3> kDirs = {
        {{0.267261f, 0.534522f, 0.801784f},
         {-0.639602f, 0.426401f, 0.639602f},
         {0.562254f, -0.749672f, 0.349215f}}};
    int insideVotes = 0;
    for (const auto& d : kDirs) {
        int crossings = 0;
        float tnear = 0.0f;
        for (int i = 0; i < 65; ++i) {
            kernels::MeshHit hit;
            const Eigen::Vector3d dir(d[0], d[1], d[2]);
            if (!kernels::intersectOne(scene, p, dir, tnear, std::numeric_limits<float>::infinity(),
                                       mask, hit))
                break;
            ++crossings;
            tnear = hit.t * (1.0f + 1e-6f) + 1e-7f;  // step past this hit
        }
        insideVotes += crossings % 2;
    }
    return insideVotes >= 2;
}

// The nearest way out of the closed surfaces of @p scene from @p p along the six axis
// directions: the exit point plus @p offset beyond it; @p p when no ray leaves.
Eigen::Vector3d nearestExit(const kernels::EmbreeScene& scene, unsigned mask,
                            const Eigen::Vector3d& p, double offset) noexcept {
    float best = std::numeric_limits<float>::infinity();
    Eigen::Vector3d out = p;
    for (int k = 0; k < 6; ++k) {
        Eigen::Vector3f d = Eigen::Vector3f::Zero();
        d[k / 2] = (k % 2) ? -1.0f : 1.0f;
        kernels::MeshHit hit;
        if (!kernels::intersectOne(scene, p, d.cast<double>(), 0.0f, best, mask, hit)) continue;
        best = hit.t;
        out = p + (static_cast<double>(best) + offset) * d.cast<double>();
    }
    return out;
}

bool sourceHasData(const Scene& scene, RaySource source) noexcept {
    switch (source) {
        case RaySource::Mesh:
            return !scene.hardMeshes().empty();
        case RaySource::VolumeFirstHit:
        case RaySource::VolumeAccumulate:
            return scene.volumeView() != nullptr;
    }
    return false;
}

// A deformable body's scene when it holds embedded (moving) hard meshes, else nullptr.
const kernels::EmbreeScene* movingMeshes(const DeformableBody* body) noexcept {
    return body != nullptr && !body->model().embedded().empty() ? &body->surfaces() : nullptr;
}

void requireSourceData(const Scene& scene, const CouplingParams& c) {
    const bool embedded = scene.deformable() && !scene.deformable()->embedded().empty();
    if (c.mode != CouplingMode::VC && !sourceHasData(scene, c.source) &&
        !(c.source == RaySource::Mesh && embedded)) {
        throw ValueError(
            c.source == RaySource::Mesh
                ? "session: expected a scene with hard meshes for RaySource::Mesh in AVC/AVCEC, "
                  "found none (add them with Scene::addHardMesh or SceneOptions::hardIso)"
                : "session: expected a scene with a volume for the volume ray sources in "
                  "AVC/AVCEC, found none (use Scene::setVolume, or CouplingMode::VC)");
    }
}

}  // namespace

void validateSessionParams(const SessionParams& params) {
    validateProxyParams(params.proxy);
    validateCouplingParams(params.coupling);
    validateServoConfig(params.servo);
    const WorkspaceTransform& w = params.workspace;
    requireWithin("session workspace.scale", w.scale, bounds::kScale);
    if (!w.rotation.allFinite()) throwExpected("session workspace.rotation", "finite", "NaN/Inf");
    for (int i = 0; i < 3; ++i)
        requireWithin("session workspace.offset", w.offset[i], bounds::kPosition);
    const double orth =
        (w.rotation.transpose() * w.rotation - Eigen::Matrix3d::Identity()).cwiseAbs().maxCoeff();
    const double det = w.rotation.determinant();
    if (orth > 1e-6 || std::abs(det - 1.0) > 1e-6) {
        throwExpected("session workspace.rotation", "a rotation (R^T R = I, det 1)",
                      "|R^T R - I| = " + formatValue(orth) + ", det " + formatValue(det));
    }
    requireWithin("session startupThresholdN", params.startupThresholdN, bounds::kPositiveForce);
    requireWithin("session crossFadeSeconds", params.crossFadeSeconds, bounds::kDuration);
    if (params.traceCapacity > kMaxTraceCapacity) {
        throwExpected("session traceCapacity", "<= " + std::to_string(kMaxTraceCapacity),
                      std::to_string(params.traceCapacity));
    }
}

namespace {

/// Most first-hit thresholds a session keeps a HitField for (a few MiB to tens of MiB each on a
/// CT); a coupling with a further threshold marches without one.
constexpr std::size_t kMaxHitFields = 8;

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
CouplingParams withField(CouplingParams p, const kernels::HitField* field) noexcept {
    p.firstHit.field = field;
    return p;
}

}  // namespace

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
          couplings{
              Coupling(scene->volumeView(), &scene->hardMeshes(),
                       withField(p.coupling, fields.get(*scene, p.coupling.firstHit.threshold)),
                       movingMeshes(body.get())),
              Coupling(scene->volumeView(), &scene->hardMeshes(),
                       withField(p.coupling, fields.get(*scene, p.coupling.firstHit.threshold)),
                       movingMeshes(body.get()))},
          fadeTicks(static_cast<std::uint32_t>(std::lround(p.crossFadeSeconds / period))),
          passivity(period, p.passivityControl,
                    spec.maxDampingNspm > 0 ? spec.maxDampingNspm
                                            : std::numeric_limits<double>::infinity(),
                    spec.maxForceN > 0 ? spec.maxForceN : std::numeric_limits<double>::infinity()),
          gate(p.startupThresholdN, p.startupQuietTicks),
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
        bool ok = false;                ///< the device's position and velocity are finite
    };
    /// What the force chain sends (stage 3 of a tick).
    struct SentForce {
        Eigen::Vector3d force;  ///< world frame, N; always finite
        bool faulted = false;   ///< the coupling's force (or the sample) was not finite
        bool clamped = false;   ///< maxForceN cut the force (before or after the damping)
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
                         double deviceScale) noexcept;
    Eigen::Vector3d worldToDevice(const Eigen::Vector3d& force) const noexcept {
        return workspace.rotation.transpose() * force;  // rotated back, not scaled
    }
    bool contactTissue(const ProxyState& ps, const Eigen::Vector3d& sent,
                       Eigen::Vector3d& tissueForce) noexcept;
    void publish(double timeSeconds, const ProxyState& ps, const SentForce& sent,
                 const Eigen::Vector3d& tissueForce) noexcept;
    void followSurface(bool anchored) noexcept;

    void setCoupling(const CouplingParams& params, bool stiffnessLimited) noexcept;
    void startFade(const CouplingParams& params, bool stiffnessLimited) noexcept;
    // The time of the tick after the newest one (0 before any), s.
    double nextTime() const noexcept { return ticks == 0 ? 0.0 : current.timeSeconds + period; }

    std::shared_ptr<const Scene> scene;
    // First-hit fields by threshold (set-up and send(); see HitFields). Declared before the
    // couplings, which are built with the starting threshold's.
    HitFields fields;
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
    DeviceHealth health;     // the device's report on this tick's sample
    bool started = false;    // the first good sample has been seen
    bool freeProxy = false;  // the probe started inside: the proxy follows it until outside
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
};

void Session::Impl::startFade(const CouplingParams& params, bool stiffnessLimited) noexcept {
    const int next = 1 - active;
    couplings[static_cast<std::size_t>(next)].setParams(params);
    limited[static_cast<std::size_t>(next)] = stiffnessLimited;
    active = next;
    if (fadeTicks == 0) {
        fading = false;
        return;
    }
    fading = true;
    fade = CrossFade(0.0);
    fade.setTarget(1.0, fadeTicks);
}

void Session::Impl::setCoupling(const CouplingParams& params, bool stiffnessLimited) noexcept {
    if (fading) {
        pending = params;
        pendingLimited = stiffnessLimited;
        hasPending = true;
    } else {
        startFade(params, stiffnessLimited);
    }
}

void Session::Impl::drainCommands() noexcept {
    // Bounded: at most the queue's capacity per tick (the producer cannot outrun a drain).
    for (std::size_t i = 0; i < commands.capacity() && commands.tryPop(command); ++i) {
        switch (command.kind) {
            case Command::Kind::SetCoupling:
                setCoupling(command.coupling, command.stiffnessLimited);
                break;
            case Command::Kind::SetAll:
                setCoupling(command.coupling, command.stiffnessLimited);
                proxy.setParams(command.proxy);
                passivity.setEnabled(command.flag);
                break;
            case Command::Kind::SetProxy:
                proxy.setParams(command.proxy);
                break;
            case Command::Kind::SetPassivityControl:
                passivity.setEnabled(command.flag);
                break;
            case Command::Kind::ResetObserver:
                passivity.reset();
                break;
        }
    }
}

void Session::Impl::tick(double timeSeconds) noexcept {
    const HandSample hand = deviceToWorld(device.read());
    health = device.health();  // a watchdog's verdict on this sample (WatchdogDevice)
    drainCommands();
    if (body) {
        // Deformable tissue: the rays leave in the material frame of the element the proxy
        // was anchored on last tick (identity in free space).
        const Eigen::Matrix3d frame = body->anchorRotation();
        for (Coupling& c : couplings) c.setMaterialFrame(frame);
    }
    const ProxyState* ps = &proxy.state();
    Eigen::Vector3d force;
    if (hand.ok) {
        const ProxyState before = proxy.state();
        lastProbeVelocity = hand.probeVelocity;
        ps = &moveProxy(hand.probe);
        coupleWithFade(*ps, hand);
        if (rejectUphillMove(before, *ps, hand)) {
            ps = &proxy.state();
            coupleWithFade(*ps, hand);
        }
        force = blended.force;
    } else {
        force.setConstant(std::numeric_limits<double>::quiet_NaN());
    }
    const SentForce sent = forceChain(force, hand.handVelocity, health.forceScale);
    device.write(worldToDevice(sent.force));
    Eigen::Vector3d tissueForce = Eigen::Vector3d::Zero();
    const bool anchored = contactTissue(*ps, sent.force, tissueForce);
    publish(timeSeconds, *ps, sent, tissueForce);
    followSurface(anchored);
}

// Stage 1, device -> world: world = offset + scale * R * device.
Session::Impl::HandSample Session::Impl::deviceToWorld(const DeviceState& state) const noexcept {
    HandSample h;
    h.handVelocity = workspace.rotation * state.velocity;
    h.probe = workspace.offset + workspace.scale * (workspace.rotation * state.position);
    h.probeVelocity = workspace.scale * h.handVelocity;
    // A sample that is not finite, or that puts the probe absurdly far away (a device driver's
    // garbage, a runaway host model), is a bad sample: no ray is cast from it (Embree asserts on
    // such rays) and the last good force is held, as for NaN.
    h.ok = h.probe.allFinite() && h.probeVelocity.allFinite() &&
           h.probe.cwiseAbs().maxCoeff() <= kMaxProbeCoordinate &&
           h.probeVelocity.cwiseAbs().maxCoeff() <= kMaxProbeSpeed;
    return h;
}

// Stage 2a (a good sample only): the proxy follows the probe, freely while the probe started
// inside an object (until it is outside), constrained by the surfaces otherwise.
const ProxyState& Session::Impl::moveProxy(const Eigen::Vector3d& probe) noexcept {
    lastProbe = probe;
    if (!started) {
        // A hand that starts inside an object must not be trapped there by its surface:
        // the proxy follows the probe freely until the probe is outside.
        freeProxy = true;
        started = true;
    }
    if (freeProxy) {
        freeProxy = insideSurfaces(body ? body->surfaces() : scene->surfaces(),
                                   proxy.params().surfaceMask, probe);
        proxy.reset(probe);
        return proxy.state();
    }
    const CouplingParams& now = couplings[static_cast<std::size_t>(active)].params();
    const double k = lastStiffness > 0 ? lastStiffness : now.baseStiffness;
    return proxy.update(probe, lastProxyForce, k, period, lastStepStiffness);
}

// Stage 2a' (AVCEC, a good sample, no cross-fade): the proxy may only move where the stored
// energy E = 1/2 k D^2 at the new probe is lower than if it had stayed (a massless proxy in a
// potential goes downhill; friction only slows it), so its motion never feeds energy into the
// coupling. An uphill move is undone (Proxy::restore) and true is returned: the caller
// computes the coupling again at the old position. Costs the centre (and ring) rays from the
// old position, and a second bundle when a move is rejected.
bool Session::Impl::rejectUphillMove(const ProxyState& before, const ProxyState& after,
                                     const HandSample& hand) noexcept {
    const auto a = static_cast<std::size_t>(active);
    if (fading || couplings[a].params().mode != CouplingMode::AVCEC || before.contactCount == 0 ||
        after.contactCount == 0 || (after.position - before.position).squaredNorm() == 0)
        return false;
    const double stay =
        couplings[a].storedEnergy(before.position, hand.probe, before.tangent1, before.tangent2);
    if (!(outputs[a].energy > stay)) return false;
    proxy.restore(before);
    return true;
}

// Stage 2b (a good sample only): the active coupling, blended with the fading-out one during a
// cross-fade (a fade that ends starts the pending one); into blended, and the proxy force and
// stiffness the next tick's proxy update uses.
void Session::Impl::coupleWithFade(const ProxyState& ps, const HandSample& hand) noexcept {
    const auto a = static_cast<std::size_t>(active);
    couplings[a].compute(ps.position, hand.probe, ps.velocity, hand.probeVelocity, ps.tangent1,
                         ps.tangent2, outputs[a]);
    if (fading) {
        const double w = fade.step();
        const std::size_t old = 1 - a;
        couplings[old].compute(ps.position, hand.probe, ps.velocity, hand.probeVelocity,
                               ps.tangent1, ps.tangent2, outputs[old]);
        blend(outputs[old], outputs[a], w, blended);
        current.fadeWeight = w;
        if (!fade.fading()) {
            fading = false;
            if (hasPending) {
                hasPending = false;
                startFade(pending, pendingLimited);
            }
        }
    } else {
        blended = outputs[a];
        current.fadeWeight = 1;
    }
    const Eigen::Vector3d extra = blended.proxyForce - blended.energyForce;
    lastProxyForce = extra.allFinite() ? extra : Eigen::Vector3d::Zero().eval();
    lastStiffness = std::isfinite(blended.stiffness) ? blended.stiffness : 0.0;
    lastStepStiffness = std::isfinite(blended.stepStiffness) ? blended.stepStiffness : 0.0;
}

// Stage 3, the force chain: guard, clamp, gate, passivity (and clamp again).
Session::Impl::SentForce Session::Impl::forceChain(const Eigen::Vector3d& couplingForce,
                                                   const Eigen::Vector3d& handVelocity,
                                                   double deviceScale) noexcept {
    SentForce out;
    out.faulted = !couplingForce.allFinite();
    const Eigen::Vector3d force = guard.filter(couplingForce);
    out.clamped = force.norm() > spec.maxForceN;
    // A device watchdog's scale (1 for a device with fresh samples) before the observer books it.
    Eigen::Vector3d sent = gate.filter(clampForce(force, spec.maxForceN)) * deviceScale;
    // The observer books the force that is actually sent (after guard, clamp and gate: always
    // finite); the controller's damping and force cut are applied before it clamps to the
    // device's maxForceN again and books the result, so W is the energy exchanged with the hand.
    sent = passivity.update(sent, handVelocity);
    out.force = sent;
    return out;
}

// Stage 5, deformable tissue (nothing on a rigid scene): the reaction of the force on the hand
// acts on the tissue at the contact and the FEM steps. Returns whether the proxy is anchored to
// the surface (it is then carried with it after publishing).
bool Session::Impl::contactTissue(const ProxyState& ps, const Eigen::Vector3d& sent,
                                  Eigen::Vector3d& tissueForce) noexcept {
    if (!body) return false;
    bool anchored = false;
    if (ps.contactCount > 0 && sent.allFinite()) {
        // Implicit coupling: the reaction of the force sent acts now, and the coupling
        // stiffness follows the tissue's motion inside the FEM substeps, so a stiff coupling
        // on soft tissue is stable (a load held over the tick rang once k exceeded the
        // tissue's local stiffness).
        body->coupleContact(ps.position, -sent, lastStiffness, spec.maxForceN, lastProbeVelocity);
        anchored = body->anchor(ps.position, ps.normals[0]);
    } else {
        body->clearForce();
    }
    const int cn = body->contactNode();
    current.femFlags = body->step(period);
    tissueForce = body->lastContactForce();
    current.contactNode = cn;
    current.maxDisplacement = body->maxSurfaceDisplacement();
    return anchored;
}

// Stage 6: the tick's Snapshot to latest() and the trace, its ray bundle to latestRays().
void Session::Impl::publish(double timeSeconds, const ProxyState& ps, const SentForce& sent,
                            const Eigen::Vector3d& tissueForce) noexcept {
    Snapshot& s = current;
    s.tick = ticks++;
    s.timeSeconds = timeSeconds;
    s.probe = lastProbe;
    s.proxy = ps.position;
    s.force = sent.force;
    s.couplingForce = blended.force;
    s.energyForce = blended.energyForce;
    s.proxyForce = blended.proxyForce;
    s.stiffness = blended.stiffness;
    s.rayLength = blended.rayLength;
    s.distance = blended.distance;
    s.couplingEnergy = blended.energy;
    s.observerEnergy = passivity.energy();
    s.addedDamping = passivity.addedDamping();
    s.passivityCut = passivity.forceCut();
    s.contactCount = ps.contactCount;
    s.rays = blended.rays;
    s.sticking = ps.sticking;
    s.gateOpen = gate.open();
    s.faulted = sent.faulted;
    s.clamped = sent.clamped;
    s.mode = couplings[static_cast<std::size_t>(active)].params().mode;
    s.stiffnessLimited = limited[static_cast<std::size_t>(active)];
    s.fading = fading;
    s.faults = guard.faultCount();
    s.tissueForce = tissueForce;
    s.deviceStale = health.stale;
    s.deviceForceScale = health.forceScale;
    s.watchdogTrips = health.trips;

    snapshots.back().value = s;
    snapshots.publish();
    rays.back().value = couplings[static_cast<std::size_t>(active)].bundle();
    rays.publish();
    if (surfaces) {
        surfaces->back().value.fill(*body, s.tick, s.timeSeconds);
        surfaces->publish();
    }
    // A full ring drops the snapshot and counts it (a ring of no slots keeps no trace).
    if (trace.capacity() > 0) {
        traceScratch.value = s;
        if (!trace.tryPush(traceScratch)) traceDropped.fetch_add(1, std::memory_order_relaxed);
    }
}

// Stage 7 (deformable scenes, after publishing: the snapshot shows the proxy the force was
// computed with): a proxy in contact is carried with the deformed surface; a free proxy that
// the moving surface overtook (a fast spring-back) is put back out along the shortest
// axis-aligned way out, 2 epsilon clear.
void Session::Impl::followSurface(bool anchored) noexcept {
    if (anchored) {
        const Eigen::Vector3d carried = body->anchoredPosition();
        if (carried.allFinite()) proxy.reset(carried);
    } else if (body && !freeProxy && started) {
        const unsigned mask = proxy.params().surfaceMask;
        const Eigen::Vector3d p = proxy.state().position;
        if (insideSurfaces(body->surfaces(), mask, p))
            proxy.reset(nearestExit(body->surfaces(), mask, p, 2 * proxy.params().epsilon));
    }
}

Session::Session(std::shared_ptr<const Scene> scene, Device& device, const SessionParams& params)
    : mParams(params) {
    validateSessionParams(params);
    if (!scene) throw ValueError("session: expected a scene, found a null pointer");
    if ((!scene->surfaces().empty() && !scene->surfaces().committed()) ||
        (!scene->hardMeshes().empty() && !scene->hardMeshes().committed())) {
        throw ValueError(
            "session: expected a committed scene, found meshes added after the last "
            "Scene::commit()");
    }
    requireSourceData(*scene, params.coupling);
    const DeviceSpec& spec = device.spec();
    requirePositive("session device maxForceN", spec.maxForceN, "N");
    if (const auto& d = scene->deformable();
        d && d->options().solverKind == DeformableSolver::asyncRegions) {
        // DeformableBody::step() refuses any other step (kStepBadTimeStep): frozen tissue.
        const double tick = d->options().regions.tickSeconds;
        const double servo = params.servo.periodSeconds;
        if (!(std::abs(tick - servo) <= 1e-9 * servo)) {
            throwExpected("session deformable regions.tickSeconds",
                          "the servo period " + formatValue(servo) + " s",
                          formatValue(tick) + " s");
        }
    }
    mStiffnessLimited = limitStiffnessToDevice(mParams.coupling, spec, mParams.servo.periodSeconds);
    mImpl = std::make_unique<Impl>(std::move(scene), device, mParams, mStiffnessLimited);
}

Session::~Session() { stop(); }

void Session::start() {
    if (mImpl->loop.running()) throw Error("session: expected a stopped session, found it running");
    mImpl->timeBase = mImpl->nextTime();
    mImpl->resyncSteps = true;
    // The hand may have moved into an object while the loop was stopped: close the start-up
    // gate again so that a restart cannot kick (the servo thread is not running here, and
    // ServoLoop::start() orders this write before its first tick).
    mImpl->gate.reset();
    mImpl->loop.start(*this);
}

void Session::stop() noexcept {
    if (mImpl) mImpl->loop.stop();
}

bool Session::running() const noexcept { return mImpl->loop.running(); }

const Snapshot& Session::step() noexcept {
    Impl& m = *mImpl;
    if (m.loop.running()) return m.stepSnapshot;
    if (m.resyncSteps) {
        // The servo thread has stopped (joined in stop()): its last tick is in current.
        m.stepOrigin = m.nextTime();
        m.stepIndex = 0;
        m.resyncSteps = false;
    }
    m.tick(m.stepOrigin + static_cast<double>(m.stepIndex++) * m.period);
    m.stepSnapshot = m.current;
    return m.stepSnapshot;
}

const Snapshot& Session::latest() noexcept { return mImpl->snapshots.read().value; }

const kernels::RayBundle& Session::latestRays() noexcept { return mImpl->rays.read().value; }

const SurfaceFrame* Session::latestSurface() noexcept {
    return mImpl->surfaces ? &mImpl->surfaces->read().value : nullptr;
}

bool Session::popTrace(Snapshot& out) noexcept {
    NothrowSlot<Snapshot> slot;
    if (!mImpl->trace.tryPop(slot)) return false;
    out = slot.value;
    return true;
}

std::uint64_t Session::traceDropped() const noexcept {
    return mImpl->traceDropped.load(std::memory_order_relaxed);
}

bool Session::send(const Command& command) {
    Command checked = command;
    checked.stiffnessLimited = false;
    switch (command.kind) {
        case Command::Kind::SetCoupling:
        case Command::Kind::SetAll:
            validateCouplingParams(command.coupling);
            requireSourceData(*mImpl->scene, command.coupling);
            if (command.kind == Command::Kind::SetAll) validateProxyParams(command.proxy);
            checked.stiffnessLimited =
                limitStiffnessToDevice(checked.coupling, mImpl->spec, mImpl->period);
            // The session's field for this threshold (built here, off the servo thread, the
            // first time the threshold is used).
            checked.coupling.firstHit.field =
                mImpl->fields.get(*mImpl->scene, checked.coupling.firstHit.threshold);
            break;
        case Command::Kind::SetProxy:
            validateProxyParams(command.proxy);
            break;
        case Command::Kind::SetPassivityControl:
        case Command::Kind::ResetObserver:
            break;
        default:
            throwExpected("session command kind", "a known Command::Kind",
                          std::to_string(static_cast<int>(command.kind)));
    }
    return mImpl->commands.tryPush(checked);
}

ServoStats Session::stats() const noexcept { return mImpl->loop.stats(); }

const RealtimeStatus& Session::realtime() const noexcept { return mImpl->loop.realtime(); }

const DeviceSpec& Session::deviceSpec() const noexcept { return mImpl->spec; }

const DeformableBody* Session::deformable() const noexcept { return mImpl->body.get(); }

std::size_t Session::hitFieldCount() const noexcept { return mImpl->fields.byThreshold.size(); }

void Session::tick(const TickInfo& info) noexcept {
    mImpl->tick(mImpl->timeBase + info.timeSeconds);
}

}  // namespace palp::haptics
