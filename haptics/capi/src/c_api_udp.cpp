// The C API's remote devices (see c_api_internal.h): a UdpDevice (the device bridge,
// docs/device_bridge.md) with its own watchdog, and the session on it.

#include <cstring>
#include <memory>
#include <string>
#include <utility>

#include "c_api_internal.h"

namespace ph = palp::haptics;

namespace palp::capi {
namespace {

constexpr const char* kOwner = "palp_udp_device_params";

/// The library names its fields ("udp device listen address 'x': ..."); a C caller set
/// palp_udp_device_params' fields. @p e's text with the first matching name replaced.
std::string asCField(const palp::Error& e) {
    static const std::pair<const char*, const char*> kNames[] = {
        {"udp device listen address", "palp_udp_device_params.listen"},
        {"udp device maxDrain", "palp_udp_device_params.max_drain"},
        {"udp device receiveBufferBytes", "palp_udp_device_params.receive_buffer_bytes"}};
    std::string what = e.what();
    for (const auto& [library, c] : kNames) {
        const std::size_t at = what.find(library);
        if (at != std::string::npos) return what.replace(at, std::strlen(library), c);
    }
    return what;
}

}  // namespace
}  // namespace palp::capi

using namespace palp::capi;

extern "C" {

void palp_udp_device_params_default(palp_udp_device_params* params) {
    if (!params) return;
    palp_udp_device_params& p = *params;
    std::memset(&p, 0, sizeof p);
    static const ph::UdpDeviceParams kDefaults;
    p.listen = kDefaults.listen.c_str();
    fromSpec(*ph::findDeviceSpec("3D Systems Touch X"), p.spec);
    p.watchdog_timeout = kDefaults.watchdog.timeoutSeconds;
    p.watchdog_grace = kDefaults.watchdog.graceSeconds;
    p.watchdog_resume = kDefaults.watchdog.resumeSeconds;
    p.max_drain = kDefaults.maxDrain;
    p.receive_buffer_bytes = kDefaults.receiveBufferBytes;
}

palp_status palp_session_create_udp(palp_scene* scene, const palp_session_params* params,
                                    const palp_udp_device_params* device, palp_session** out) {
    if (!scene) return nullArgument("palp_session_create_udp", "scene");
    if (!params) return nullArgument("palp_session_create_udp", "params");
    if (!device) return nullArgument("palp_session_create_udp", "device");
    if (!device->listen) return nullArgument("palp_session_create_udp", "device->listen");
    if (!out) return nullArgument("palp_session_create_udp", "out");
    return guarded([&] {
        auto handle = std::make_unique<palp_session>();
        handle->deviceName = device->name ? device->name : "udp device";
        const ph::DeviceSpec spec = toSpec(device->spec, handle->deviceName, kOwner);
        ph::UdpDeviceParams dp;
        dp.listen = device->listen;
        dp.watchdog = toWatchdog(device->watchdog_timeout, device->watchdog_grace,
                                 device->watchdog_resume, kOwner);
        dp.maxDrain = device->max_drain;
        dp.receiveBufferBytes = device->receive_buffer_bytes;
        ph::SessionParams sp = toSession(*params);
        sp.faults = faultsLike(dp.watchdog);  // the session's fault ramp as the watchdog's
        dp.periodSeconds = sp.servo.periodSeconds;
        checkScenePeriod(*scene, params->period, "palp_session_create_udp");
        std::unique_ptr<ph::UdpDevice> udp;
        try {
            udp = std::make_unique<ph::UdpDevice>(spec, dp);
        } catch (const palp::IoError& e) {
            throw palp::IoError(asCField(e));
        } catch (const palp::ValueError& e) {
            throw palp::ValueError(asCField(e));
        }
        handle->params = *params;
        handle->params.device = handle->deviceName.c_str();
        handle->udp = udp.get();
        handle->device = std::move(udp);
        handle->session = std::make_unique<ph::Session>(scene->scene, *handle->device, sp);
        handle->params.stiffness = handle->session->params().coupling.baseStiffness;
        handle->params.max_stiffness = handle->session->params().coupling.maxStiffness;
        *out = handle.release();
        return PALP_OK;
    });
}

int palp_session_udp_port(const palp_session* session) {
    return session && session->udp ? session->udp->port() : 0;
}

const char* palp_session_udp_address(const palp_session* session) {
    return session && session->udp ? session->udp->address().c_str() : nullptr;
}

palp_status palp_session_udp_state(palp_session* session, palp_udp_state* out) {
    if (!session) return nullArgument("palp_session_udp_state", "session");
    if (!out) return nullArgument("palp_session_udp_state", "out");
    if (!session->udp) {
        return fail(PALP_ERROR_STATE,
                    "palp_session_udp_state: expected a session made by palp_session_create_udp, "
                    "found another device's");
    }
    const ph::bridge::StateMessage& m = session->udp->publishedState();
    out->sequence = m.sequence;
    out->time_ns = m.timeNs;
    put(m.position, out->position);
    out->orientation[0] = m.orientation.w();
    out->orientation[1] = m.orientation.x();
    out->orientation[2] = m.orientation.y();
    out->orientation[3] = m.orientation.z();
    put(m.velocity, out->velocity);
    out->buttons = m.buttons;
    return PALP_OK;
}

palp_status palp_session_udp_counters(const palp_session* session, palp_udp_device_counters* out) {
    if (!session) return nullArgument("palp_session_udp_counters", "session");
    if (!out) return nullArgument("palp_session_udp_counters", "out");
    if (!session->udp) {
        return fail(PALP_ERROR_STATE,
                    "palp_session_udp_counters: expected a session made by "
                    "palp_session_create_udp, found another device's");
    }
    const ph::UdpDeviceCounters c = session->udp->counters();
    palp_udp_device_counters& o = *out;
    o.received = c.received;
    o.superseded = c.superseded;
    o.lost = c.lost;
    o.late = c.late;
    o.restarts = c.restarts;
    o.peer_changes = c.peerChanges;
    o.ignored = c.ignored();
    o.short_datagrams = c.shortDatagrams;
    o.bad_magic = c.badMagic;
    o.bad_version = c.badVersion;
    o.bad_type = c.badType;
    o.bad_size = c.badSize;
    o.receive_errors = c.receiveErrors;
    o.drain_limited = c.drainLimited;
    o.forces_sent = c.sent;
    o.forces_send_failed = c.sendFailed;
    return PALP_OK;
}

}  // extern "C"
