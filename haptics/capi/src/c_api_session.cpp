// The C API's sessions (see c_api_internal.h): create a simulated session, run it, step it,
// read its snapshots, trace and statistics, and change its parameters while it runs.

#include <cmath>
#include <cstring>
#include <memory>
#include <mutex>
#include <string>

#include "c_api_internal.h"
#include "palp/base/validate.h"

namespace ph = palp::haptics;

namespace palp::capi {

void checkScenePeriod(const palp_scene& scene, double period, const char* function) {
    if (const double t = deformablePeriod(scene); t > 0 && !(std::abs(t - period) <= 1e-9 * t)) {
        palp::throwExpected(std::string(function) + ": palp_session_params.period",
                            "the deformable scene's palp_deformable_options.period (" +
                                palp::formatValue(t) + " s)",
                            palp::formatValue(period) + " s");
    }
}

}  // namespace palp::capi

using namespace palp::capi;

extern "C" {

palp_status palp_session_create_simulated(palp_scene* scene, const palp_session_params* params,
                                          const palp_trajectory* trajectory, palp_session** out) {
    if (!scene) return nullArgument("palp_session_create_simulated", "scene");
    if (!params) return nullArgument("palp_session_create_simulated", "params");
    if (!trajectory) return nullArgument("palp_session_create_simulated", "trajectory");
    if (!out) return nullArgument("palp_session_create_simulated", "out");
    return guarded([&] {
        const ph::DeviceSpec& spec = deviceSpec(params->device);
        const ph::SessionParams sp = toSession(*params);
        const ph::Trajectory path = toTrajectory(*trajectory);
        const ph::HandModel hand = toHand(*trajectory);
        checkScenePeriod(*scene, params->period, "palp_session_create_simulated");
        auto handle = std::make_unique<palp_session>();
        handle->deviceName = params->device;
        handle->params = *params;
        handle->params.device = handle->deviceName.c_str();
        handle->device =
            std::make_unique<ph::SimulatedDevice>(spec, path, hand, sp.servo.periodSeconds);
        handle->session = std::make_unique<ph::Session>(scene->scene, *handle->device, sp);
        // The stiffness in force: lowered to the device's limit when above it.
        handle->params.stiffness = handle->session->params().coupling.baseStiffness;
        handle->params.max_stiffness = handle->session->params().coupling.maxStiffness;
        *out = handle.release();
        return PALP_OK;
    });
}

palp_session* palp_session_retain(palp_session* session) { return retain(session); }
void palp_session_release(palp_session* session) { release(session); }

palp_status palp_session_start(palp_session* session) {
    if (!session) return nullArgument("palp_session_start", "session");
    if (session->session->running()) {
        return fail(PALP_ERROR_STATE,
                    "palp_session_start: expected a stopped session, found it running");
    }
    return guarded([&] {
        try {
            session->session->start();
        } catch (const palp::ValueError&) {
            throw;
        } catch (const palp::Error& e) {
            bool requireRealtime = false;
            {
                const std::lock_guard<std::mutex> lock(session->paramsMutex);
                requireRealtime = session->params.require_realtime != 0;
            }
            return fail(requireRealtime ? PALP_ERROR_REALTIME : PALP_ERROR_STATE, e.what());
        }
        return PALP_OK;
    });
}

palp_status palp_session_stop(palp_session* session) {
    if (!session) return nullArgument("palp_session_stop", "session");
    session->session->stop();
    return PALP_OK;
}

int palp_session_running(const palp_session* session) {
    return session && session->session->running() ? 1 : 0;
}

palp_status palp_session_step(palp_session* session, uint32_t ticks, palp_snapshot* last) {
    if (!session) return nullArgument("palp_session_step", "session");
    if (session->session->running()) {
        return fail(PALP_ERROR_STATE,
                    "palp_session_step: expected a stopped session, found its servo thread "
                    "running (call palp_session_stop first)");
    }
    const ph::Snapshot* s = &session->session->newest();  // ticks 0: the newest as it is
    for (uint32_t i = 0; i < ticks; ++i) s = &session->session->step();
    if (last) toC(*s, *last);
    return PALP_OK;
}

palp_status palp_session_latest(palp_session* session, palp_snapshot* out) {
    if (!session) return nullArgument("palp_session_latest", "session");
    if (!out) return nullArgument("palp_session_latest", "out");
    toC(session->session->latest(), *out);
    return PALP_OK;
}

palp_status palp_session_pop_trace(palp_session* session, palp_snapshot* out, int* got) {
    if (!session) return nullArgument("palp_session_pop_trace", "session");
    if (!out) return nullArgument("palp_session_pop_trace", "out");
    if (!got) return nullArgument("palp_session_pop_trace", "got");
    ph::Snapshot s;
    *got = session->session->popTrace(s) ? 1 : 0;
    if (*got) toC(s, *out);
    return PALP_OK;
}

palp_status palp_session_set_params(palp_session* session, const palp_session_params* params) {
    if (!session) return nullArgument("palp_session_set_params", "session");
    if (!params) return nullArgument("palp_session_set_params", "params");
    return guarded([&] {
        const std::lock_guard<std::mutex> lock(session->paramsMutex);
        if (const char* field = fixedFieldChanged(session->params, *params)) {
            throw palp::ValueError(std::string("palp_session_set_params: expected ") + field +
                                   " to stay as at creation (it cannot change while a session "
                                   "exists), found a different value");
        }
        // One SetAll command: the coupling, friction and passivity changes take one queue slot
        // and land on the same tick, so a full queue refuses all of them (all or nothing).
        ph::Command all;
        all.kind = ph::Command::Kind::SetAll;
        all.coupling = toCoupling(*params);
        all.proxy = toProxy(*params);
        all.flag = params->passivity_control != 0;
        ph::CouplingParams inForce = all.coupling;  // what the session renders (see send())
        ph::limitStiffnessToDevice(inForce, session->session->deviceSpec(),
                                   session->session->params().servo.periodSeconds);
        if (!session->session->send(all)) {  // validates everything before queueing anything
            return fail(PALP_ERROR_QUEUE_FULL,
                        "palp_session_set_params: command queue full (nothing applied)");
        }
        palp_session_params& now = session->params;
        const char* device = now.device;
        now = *params;
        now.device = device;
        now.stiffness = inForce.baseStiffness;
        now.max_stiffness = inForce.maxStiffness;
        return PALP_OK;
    });
}

palp_status palp_session_set_mode(palp_session* session, palp_coupling_mode mode) {
    if (!session) return nullArgument("palp_session_set_mode", "session");
    return guarded([&] {
        const std::lock_guard<std::mutex> lock(session->paramsMutex);
        palp_session_params p = session->params;
        std::memcpy(&p.mode, &mode, sizeof mode);  // checked by toCoupling (rawEnum)
        ph::Command c;
        c.kind = ph::Command::Kind::SetCoupling;
        c.coupling = toCoupling(p);
        if (!session->session->send(c)) {
            return fail(PALP_ERROR_QUEUE_FULL, "palp_session_set_mode: command queue full");
        }
        session->params.mode = p.mode;
        return PALP_OK;
    });
}

palp_status palp_session_get_params(const palp_session* session, palp_session_params* out) {
    if (!session) return nullArgument("palp_session_get_params", "session");
    if (!out) return nullArgument("palp_session_get_params", "out");
    const std::lock_guard<std::mutex> lock(session->paramsMutex);
    *out = session->params;
    return PALP_OK;
}

palp_status palp_session_reset_observer(palp_session* session) {
    if (!session) return nullArgument("palp_session_reset_observer", "session");
    return guarded([&] {
        ph::Command c;
        c.kind = ph::Command::Kind::ResetObserver;
        if (!session->session->send(c)) {
            return fail(PALP_ERROR_QUEUE_FULL, "palp_session_reset_observer: command queue full");
        }
        return PALP_OK;
    });
}

palp_status palp_session_stats(const palp_session* session, palp_loop_stats* out) {
    if (!session) return nullArgument("palp_session_stats", "session");
    if (!out) return nullArgument("palp_session_stats", "out");
    const ph::ServoStats s = session->session->stats();
    out->wake_latency = toC(s.wakeLatency);
    out->period_error = toC(s.periodError);
    out->compute = toC(s.compute);
    out->ticks = s.ticks;
    out->misses = s.misses;
    out->skipped = s.skipped;
    out->trace_dropped = session->session->traceDropped();
    out->overloaded = s.overloaded ? 1 : 0;
    out->fifo_dropped = s.fifoDropped ? 1 : 0;
    out->overloaded_at = s.overloadedAtSeconds;
    out->shedding = s.shedding ? 1 : 0;
    out->sheds = s.sheds;
    out->restores = s.restores;
    out->shed_at = s.shedAtSeconds;
    return PALP_OK;
}

palp_status palp_session_realtime(const palp_session* session, palp_realtime* out) {
    if (!session) return nullArgument("palp_session_realtime", "session");
    if (!out) return nullArgument("palp_session_realtime", "out");
    const ph::RealtimeStatus& r = session->session->realtime();
    out->pinned = r.pinned ? 1 : 0;
    out->cpu = r.cpu;
    out->fifo = r.fifo ? 1 : 0;
    out->priority = r.priority;
    out->memory_locked = r.memoryLocked ? 1 : 0;
    out->failed = r.failed ? 1 : 0;
    out->message = r.message.c_str();
    return PALP_OK;
}

const char* palp_session_realtime_status(const palp_session* session) {
    return session ? session->session->realtime().message.c_str() : nullptr;
}

}  // extern "C"
