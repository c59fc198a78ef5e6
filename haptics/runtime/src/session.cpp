// Session's set-up and the side of the threads other than the servo thread: parameter and
// scene checks, construction, start/stop, offline step(), the viewer's latest*(), the trace
// reader's popTrace() and the producer's send() (commands checked and their first-hit field
// built here, off the servo thread). The servo thread's tick is in session_tick.cpp.
#include "palp/haptics/session.h"

#include <cmath>
#include <string>

#include "palp/base/bounds.h"
#include "palp/base/error.h"
#include "palp/base/validate.h"
#include "palp/haptics/devices/fault_ramp.h"
#include "session_impl.h"

namespace palp::haptics {
namespace {

constexpr std::uint32_t kMaxTraceCapacity = 1u << 24;  // 16 M snapshots (a few GB): a typo guard

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
    const FaultParams& f = params.faults;
    validateFaultRampTimes("session faults.", f.graceSeconds, f.timeoutSeconds, f.resumeSeconds);
    requireWithin("session faults.maxForceStepN (0: half the device's maxForceN)", f.maxForceStepN,
                  bounds::kForce);
    requireWithin("session recontact.seconds", params.recontact.seconds, bounds::kWindow);
    requireWithin("session recontact.riseNps", params.recontact.riseNps, bounds::kForceRate);
    if (params.traceCapacity > kMaxTraceCapacity) {
        throwExpected("session traceCapacity", "<= " + std::to_string(kMaxTraceCapacity),
                      std::to_string(params.traceCapacity));
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
    mImpl->overloaded = false;  // a new run gets a new overrun budget
    mImpl->restore();           // and its work back (the servo thread is not running here)
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
    m.offlineStep = true;
    m.tick(m.stepOrigin + static_cast<double>(m.stepIndex++) * m.period);
    m.offlineStep = false;
    m.stepSnapshot = m.current;
    return m.stepSnapshot;
}

const Snapshot& Session::newest() const noexcept {
    return mImpl->loop.running() ? mImpl->stepSnapshot : mImpl->current;
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

void Session::overloaded() noexcept { mImpl->overloaded = true; }  // on the servo thread

bool Session::shed() noexcept { return mImpl->shed(); }  // on the servo thread

void Session::restore() noexcept { mImpl->restore(); }  // on the servo thread

void Session::tick(const TickInfo& info) noexcept {
    mImpl->tick(mImpl->timeBase + info.timeSeconds);
}

}  // namespace palp::haptics
