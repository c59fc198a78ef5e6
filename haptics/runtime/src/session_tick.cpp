// Session's servo thread: one tick (device -> world, commands, proxy, coupling with its
// cross-fade, the force chain, deformable tissue, publishing the snapshot, rays and trace, the
// proxy carried with a deformed surface). Everything here is noexcept, allocation-free,
// lock-free and bounded. Set-up and the other threads' side are in session.cpp.
#include <algorithm>
#include <array>
#include <cmath>
#include <limits>

#include "palp/haptics/session.h"
#include "session_impl.h"

namespace palp::haptics {
namespace {

/// Largest |coordinate| (m) of a probe sample taken as real: a thousand times palp's world
/// bound (bounds::kPosition), far inside what Embree's rays accept.
constexpr double kMaxProbeCoordinate = 1e4;
/// Largest |velocity component| (m/s) of a probe sample taken as real.
constexpr double kMaxProbeSpeed = 1e4;

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

// Whether @p p lies inside a deformable body's surface (geometries of @p mask): the body's
// boundary is closed and its triangles are counter-clockwise seen from outside, so the first
// surface a ray from inside meets faces away from it (its outward normal along the ray). One
// closest-hit query per direction (majority of three) instead of insideSurfaces' walk through
// every crossing, which on a patient's body (nested shells, rays across the head) took most of
// the slowest servo ticks. Bounded: 3 ray queries (7 us on average on the head CT's skin).
bool insideBody(const kernels::EmbreeScene& scene, unsigned mask,
                const Eigen::Vector3d& p) noexcept {
    if (scene.empty() || !scene.committed() || !p.allFinite()) return false;
    static constexpr std::array<std::array<double, 3>, 3> kDirs = {
        {{0.267261, 0.534522, 0.801784},
         {-0.639602, 0.426401, 0.639602},
         {0.562254, -0.749672, 0.349215}}};
    int insideVotes = 0;
    for (const auto& d : kDirs) {
        const Eigen::Vector3d dir(d[0], d[1], d[2]);
        kernels::MeshHit hit;
        if (!kernels::intersectOne(scene, p, dir, 0.0f, std::numeric_limits<float>::infinity(),
                                   mask, hit))
            continue;
        std::array<Eigen::Vector3f, 3> c;
        if (!scene.triangle(hit.geomId, hit.primId, c)) continue;
        const Eigen::Vector3f outward = (c[1] - c[0]).cross(c[2] - c[0]);
        if (outward.cast<double>().dot(dir) > 0.0) ++insideVotes;
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

}  // namespace

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

void Session::Impl::requestCoupling(const CouplingParams& params, bool stiffnessLimited) noexcept {
    shedCoupling = shedding && params.mode != CouplingMode::VC;
    if (!shedCoupling) {
        setCoupling(params, stiffnessLimited);
        return;
    }
    wanted = params;
    wantedLimited = stiffnessLimited;
    CouplingParams vc = params;
    vc.mode = CouplingMode::VC;
    setCoupling(vc, stiffnessLimited);
}

bool Session::Impl::shed() noexcept {
    if (overloaded || shedding) return false;
    // The newest coupling asked for: one waiting for a fade to end, else the active one.
    const auto a = static_cast<std::size_t>(active);
    const CouplingParams now = hasPending ? pending : couplings[a].params();
    const bool nowLimited = hasPending ? pendingLimited : limited[a];
    shedding = now.mode != CouplingMode::VC || body != nullptr;
    if (shedding) requestCoupling(now, nowLimited);
    return shedding;
}

void Session::Impl::restore() noexcept {
    if (!shedding) return;
    shedding = false;
    if (shedCoupling) {
        shedCoupling = false;
        setCoupling(wanted, wantedLimited);
    }
}

void Session::Impl::drainCommands() noexcept {
    // Bounded: at most the queue's capacity per tick (the producer cannot outrun a drain).
    for (std::size_t i = 0; i < commands.capacity() && commands.tryPop(command); ++i) {
        switch (command.kind) {
            case Command::Kind::SetCoupling:
                requestCoupling(command.coupling, command.stiffnessLimited);
                break;
            case Command::Kind::SetAll:
                requestCoupling(command.coupling, command.stiffnessLimited);
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
    HandSample hand = deviceToWorld(device.read());
    health = device.health();  // a watchdog's verdict on this sample (WatchdogDevice)
    // A sample the device's watchdog marks bad is refused exactly as one the session finds bad.
    hand.ok = hand.ok && (health.faults & kBadSampleFaults) == 0;
    drainCommands();
    if (body) {
        // Deformable tissue: the rays leave in the material frame of the element the proxy
        // was anchored on last tick (identity in free space).
        const Eigen::Matrix3d frame = body->anchorRotation();
        for (Coupling& c : couplings) {
            c.setMaterialFrame(frame);
            c.beginTick(period);  // k's filter against the tissue-proxy loop
        }
    }
    const ProxyState* ps = &proxy.state();
    Eigen::Vector3d force;
    if (overloaded) {
        // The loop overran its budget: shed everything (no proxy, rays or FEM); the last good
        // force is held (not a fault of the force: faulted stays clear) and ramped to zero.
        hand.faults |= kFaultOverload;
        force = guard.lastGood();
        blended.rays = 0;  // none cast (the snapshot keeps the last coupling's other figures)
    } else if (hand.ok) {
        const ProxyState before = proxy.state();
        lastProbeVelocity = hand.probeVelocity;
        ps = &moveProxy(hand.probe);
        coupleWithFade(*ps, hand);
        if (rejectUphillMove(before, *ps, hand)) {
            ps = &proxy.state();
            coupleWithFade(*ps, hand);
        }
        force = blended.force;
        if (recontactLimiting) {
            // After the tissue sprang back past the free probe (followSurface): the magnitude
            // rises by at most recontactRise a tick (the direction kept) while the dent forms
            // again under the load the tissue receives (the force sent). Past the window the
            // limit holds until the coupling's force is within it, so its end is no step.
            if (recontactLeft > 0) --recontactLeft;
            const double n = force.norm();
            const double cap = recontactLast + recontactRise;
            if (n > cap) {
                force *= cap / n;
                recontactLast = cap;
            } else {
                recontactLast = n;
                recontactLimiting = recontactLeft > 0;
            }
        }
    } else {
        force.setConstant(std::numeric_limits<double>::quiet_NaN());
    }
    if (shedding && !overloaded) hand.faults |= kFaultShed;
    const SentForce sent =
        forceChain(force, hand.handVelocity, health.forceScale, !hand.ok || overloaded);
    const std::uint32_t faults = (health.faults & kAllFaults) | hand.faults | sent.faults;
    countFaults(faults);
    current.faultFlags = faults;
    device.reportFaults(faults, sent.scale);
    device.write(worldToDevice(sent.force));
    Eigen::Vector3d tissueForce = Eigen::Vector3d::Zero();
    const bool anchored = !overloaded && contactTissue(*ps, sent.force, tissueForce);
    publish(timeSeconds, *ps, sent, tissueForce);
    if (!overloaded) followSurface(anchored);
}

// Stage 1, device -> world: world = offset + scale * R * device.
Session::Impl::HandSample Session::Impl::deviceToWorld(const DeviceState& state) const noexcept {
    HandSample h;
    h.handVelocity = workspace.rotation * state.velocity;
    h.probe = workspace.offset + workspace.scale * (workspace.rotation * state.position);
    h.probeVelocity = workspace.scale * h.handVelocity;
    // A sample that is not finite, or that puts the probe absurdly far away (a device driver's
    // garbage, a runaway host model), is a bad sample: no ray is cast from it (Embree asserts on
    // such rays) and the last good force is held, then ramped to zero, as for NaN.
    if (!(h.probe.allFinite() && h.probeVelocity.allFinite())) {
        h.faults = kFaultNonFinite;
    } else {
        if (h.probe.cwiseAbs().maxCoeff() > kMaxProbeCoordinate) h.faults |= kFaultOutOfRange;
        if (h.probeVelocity.cwiseAbs().maxCoeff() > kMaxProbeSpeed) h.faults |= kFaultTooFast;
    }
    h.ok = h.faults == 0;
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
        const unsigned mask = proxy.params().surfaceMask;
        freeProxy = body ? insideBody(body->surfaces(), mask, probe)
                         : insideSurfaces(scene->surfaces(), mask, probe);
        proxy.reset(probe);
        return proxy.state();
    }
    const CouplingParams& now = couplings[static_cast<std::size_t>(active)].params();
    const double k = lastStiffness > 0 ? lastStiffness : now.baseStiffness;
    // On deformable tissue the spring's share of the slide is not damped (the proxy follows
    // the probe as in AVC: a lag of tenths of a millimetre, against a coupling stretch D of
    // 0.25-0.6 mm there, tilted d past the bone); on rigid scenes the whole slide stays damped
    // (undamped, the AVC box edge's frictionless circles with accumulate gave the hand
    // +0.35 mJ, above 5 % of AVC's +1.70: docs/algorithms.md section 3).
    return proxy.update(probe, lastProxyForce, k, period, lastStepStiffness, body ? k : 0.0);
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

// Stage 3, the force chain: guard, clamp, gate, step limit, the fault ramps' scale, passivity
// (and clamp again).
Session::Impl::SentForce Session::Impl::forceChain(const Eigen::Vector3d& couplingForce,
                                                   const Eigen::Vector3d& handVelocity,
                                                   double deviceScale,
                                                   bool sampleRefused) noexcept {
    SentForce out;
    out.faulted = !couplingForce.allFinite();
    // A refused sample's NaN is the session's own doing; only a computed force is a force fault.
    if (out.faulted && !sampleRefused) out.faults |= kFaultForceNonFinite;
    const Eigen::Vector3d force = guard.filter(couplingForce);
    out.clamped = force.norm() > spec.maxForceN;
    const Eigen::Vector3d stepped = limitStep(gate.filter(clampForce(force, spec.maxForceN)), out);
    // A tick with a refused sample, a non-finite force or a limited step counts as missing for
    // the session's ramp, exactly as a missing sample does for a device's watchdog.
    const bool bad = sampleRefused || out.faults != 0;
    const double own = bad ? faultRamp.bad() : faultRamp.good();
    out.scale = std::min(deviceScale, own);
    // The observer books the force that is actually sent (after guard, clamp, gate and the
    // ramps: always finite); the controller's damping and force cut are applied before it clamps
    // to the device's maxForceN again and books the result, so W is the energy exchanged with
    // the hand.
    out.force = passivity.update(stepped * out.scale, handVelocity);
    return out;
}

// The force may change by at most maxForceStep per tick (a drop to exactly zero, a cut, always
// passes); a larger change is limited and flagged.
Eigen::Vector3d Session::Impl::limitStep(const Eigen::Vector3d& force, SentForce& out) noexcept {
    const Eigen::Vector3d change = force - lastStepped;
    const double n = change.norm();
    if (n > maxForceStep && !(force.array() == 0.0).all()) {
        lastStepped += change * (maxForceStep / n);
        out.faults |= kFaultForceJump;
    } else {
        lastStepped = force;
    }
    return lastStepped;
}

void Session::Impl::countFaults(std::uint32_t faults) noexcept {
    FaultCounts& c = faultCounts;
    c.stale += (faults & kFaultStale) ? 1 : 0;
    c.nonFinite += (faults & kFaultNonFinite) ? 1 : 0;
    c.outOfRange += (faults & kFaultOutOfRange) ? 1 : 0;
    c.tooFast += (faults & kFaultTooFast) ? 1 : 0;
    c.forceNonFinite += (faults & kFaultForceNonFinite) ? 1 : 0;
    c.forceJump += (faults & kFaultForceJump) ? 1 : 0;
    c.overload += (faults & kFaultOverload) ? 1 : 0;
    c.shed += (faults & kFaultShed) ? 1 : 0;
}

// Stage 5, deformable tissue (nothing on a rigid scene): the reaction of the force on the hand
// acts on the tissue at the contact and the FEM steps. Returns whether the proxy is anchored to
// the surface (it is then carried with it after publishing).
bool Session::Impl::contactTissue(const ProxyState& ps, const Eigen::Vector3d& sent,
                                  Eigen::Vector3d& tissueForce) noexcept {
    if (!body) return false;
    if (shedding) {
        // Shed: the tissue keeps its shape (no load, no step); the proxy rests on it as on a
        // rigid surface. The snapshot shows no contact on the tissue.
        current.femFlags = 0;
        current.contactNode = -1;
        return false;
    }
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
    s.deviceForceScale = sent.scale;
    s.watchdogTrips = health.trips;
    s.faultCounts = faultCounts;
    s.faultTrips = faultRamp.trips();  // s.faultFlags was set by tick()

    snapshots.back().value = s;
    snapshots.publish();
    rays.back().value = couplings[static_cast<std::size_t>(active)].bundle();
    rays.publish();
    // The surface for a viewer: every offline step, and every kSurfaceFrameTicks-th tick live
    // (a copy of every vertex: 0.14 ms a tick on the head CT's 2.5 mm skin, for a display that
    // draws at most one frame in 8 ticks).
    if (surfaces && (offlineStep || s.tick % kSurfaceFrameTicks == 0)) {
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
        // carry(), not reset(): the proxy stays in contact, so AVCEC's downhill rule and the
        // proxy's own potential rule act on tissue as on a rigid surface.
        if (carried.allFinite()) proxy.carry(carried);
    } else if (body && !freeProxy && started) {
        const unsigned mask = proxy.params().surfaceMask;
        const Eigen::Vector3d p = proxy.state().position;
        if (insideBody(body->surfaces(), mask, p)) {
            proxy.reset(nearestExit(body->surfaces(), mask, p, 2 * proxy.params().epsilon));
            recontactLeft = recontactTicks;
            recontactLast = 0;
            recontactLimiting = recontactTicks > 0;
        }
    }
}

}  // namespace palp::haptics
