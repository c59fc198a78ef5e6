// The C API's host devices (see c_api_internal.h): a Device made of the host's callbacks,
// watched by a WatchdogDevice, and the session on it.

#include <array>
#include <cstring>
#include <memory>
#include <string>

#include "c_api_internal.h"
#include "palp/base/bounds.h"
#include "palp/base/validate.h"

namespace ph = palp::haptics;

namespace palp::capi {
namespace {

/// The host's callbacks as a Device. read_state gets the last sample to overwrite; a non-zero
/// return leaves it as it was, which the watchdog sees as no new sample.
class CallbackDevice final : public ph::Device {
  public:
    CallbackDevice(const palp_device_callbacks& c, const ph::DeviceSpec& spec)
        : mRead(c.read_state), mWrite(c.write_force), mUser(c.user), mSpec(spec) {
        std::memset(&mState, 0, sizeof mState);
    }

    ph::DeviceState read() noexcept override {
        palp_device_state next = mState;
        if (mRead(mUser, &next) == 0) mState = next;
        ph::DeviceState s;
        s.position = vec(mState.position);
        s.velocity = vec(mState.velocity);
        s.buttons = mState.buttons;
        s.sequence = mState.sequence;
        s.timestampSeconds = mState.timestamp;
        return s;
    }
    void write(const Eigen::Vector3d& forceN) noexcept override {
        if (!mWrite) return;
        const std::array<double, 3> f{forceN.x(), forceN.y(), forceN.z()};
        mWrite(mUser, f.data());
    }
    const ph::DeviceSpec& spec() const noexcept override { return mSpec; }

  private:
    palp_device_read_fn mRead;
    palp_device_write_fn mWrite;
    void* mUser;
    ph::DeviceSpec mSpec;  // its name points into the session handle's deviceName
    palp_device_state mState;
};

}  // namespace

ph::DeviceSpec toSpec(const palp_device_spec& c, std::string_view name, const char* owner) {
    const auto specField = [owner](const char* field) { return std::string(owner) + "." + field; };
    requireWithin(specField("spec.max_force"), c.max_force, bounds::kPositiveForce);
    requireWithin(specField("spec.max_continuous_force"), c.max_continuous_force, bounds::kForce);
    requireWithin(specField("spec.max_stiffness (0: no limit)"), c.max_stiffness,
                  bounds::kStiffness);
    requireWithin(specField("spec.max_damping (0: no limit)"), c.max_damping, bounds::kDamping);
    for (int i = 0; i < 3; ++i) {
        const std::string k = "[" + std::to_string(i) + "]";
        requireWithin(specField("spec.workspace_min") + k, c.workspace_min[i], bounds::kPosition);
        requireWithin(specField("spec.workspace_max") + k, c.workspace_max[i], bounds::kPosition);
        if (!(c.workspace_max[i] >= c.workspace_min[i])) {
            throwExpected(
                specField("spec.workspace_max") + k,
                "at least workspace_min" + k + " (" + formatValue(c.workspace_min[i]) + " m)",
                formatValue(c.workspace_max[i]));
        }
    }
    ph::DeviceSpec s;
    s.name = name;
    s.maxForceN = c.max_force;
    s.maxContinuousForceN = c.max_continuous_force;
    s.maxStiffnessNpm = c.max_stiffness;  // 0: limitStiffnessToDevice ignores it
    s.maxDampingNspm = c.max_damping;
    s.workspace.min = vec(c.workspace_min);
    s.workspace.max = vec(c.workspace_max);
    return s;
}

ph::WatchdogParams toWatchdog(double timeout, double grace, double resume, const char* owner) {
    ph::WatchdogParams w;
    w.timeoutSeconds = timeout;
    w.graceSeconds = grace;
    w.resumeSeconds = resume;
    try {
        ph::validateWatchdogParams(w);
    } catch (const palp::ValueError& e) {
        // The library names its members; say which C fields they are.
        throw palp::ValueError(std::string(owner) +
                               ".watchdog_timeout/_grace/_resume: " + e.what());
    }
    return w;
}

ph::FaultParams faultsLike(const ph::WatchdogParams& w) noexcept {
    ph::FaultParams f;
    f.graceSeconds = w.graceSeconds;
    f.timeoutSeconds = w.timeoutSeconds;
    f.resumeSeconds = w.resumeSeconds;
    return f;
}

void fromSpec(const ph::DeviceSpec& s, palp_device_spec& c) noexcept {
    c.max_force = s.maxForceN;
    c.max_continuous_force = s.maxContinuousForceN;
    c.max_stiffness = s.maxStiffnessNpm;
    c.max_damping = s.maxDampingNspm;
    put(s.workspace.min, c.workspace_min);
    put(s.workspace.max, c.workspace_max);
}

palp_session* makeHostSession(std::shared_ptr<const ph::Scene> scene, ph::SessionParams sp,
                              const palp_session_params& cParams,
                              const palp_device_callbacks& device) {
    auto handle = std::make_unique<palp_session>();
    handle->deviceName = device.name ? device.name : "host device";
    const ph::DeviceSpec spec = toSpec(device.spec, handle->deviceName, "palp_device_callbacks");
    const ph::WatchdogParams watch = toWatchdog(device.watchdog_timeout, device.watchdog_grace,
                                                device.watchdog_resume, "palp_device_callbacks");
    sp.faults = faultsLike(watch);  // the session's fault ramp as the watchdog's
    handle->params = cParams;
    handle->params.device = handle->deviceName.c_str();
    handle->device = std::make_unique<CallbackDevice>(device, spec);
    handle->watchdog =
        std::make_unique<ph::WatchdogDevice>(*handle->device, watch, sp.servo.periodSeconds);
    handle->session = std::make_unique<ph::Session>(std::move(scene), *handle->watchdog, sp);
    handle->params.stiffness = handle->session->params().coupling.baseStiffness;
    handle->params.max_stiffness = handle->session->params().coupling.maxStiffness;
    return handle.release();
}

}  // namespace palp::capi

using namespace palp::capi;

extern "C" {

palp_status palp_device_spec_from_class(const char* device_class, palp_device_spec* out) {
    if (!device_class) return nullArgument("palp_device_spec_from_class", "device_class");
    if (!out) return nullArgument("palp_device_spec_from_class", "out");
    return guarded([&] {
        if (!ph::findDeviceSpec(device_class)) {
            std::string choices;
            for (const ph::DeviceSpec& s : ph::deviceSpecs()) {
                choices += (choices.empty() ? "'" : ", '") + std::string(s.name) + "'";
            }
            palp::throwExpected("palp_device_spec_from_class: device_class", "one of " + choices,
                                std::string("'") + device_class + "'");
        }
        fromSpec(*ph::findDeviceSpec(device_class), *out);
        return PALP_OK;
    });
}

void palp_device_callbacks_default(palp_device_callbacks* callbacks) {
    if (!callbacks) return;
    palp_device_callbacks& c = *callbacks;
    std::memset(&c, 0, sizeof c);
    fromSpec(*ph::findDeviceSpec("3D Systems Touch X"), c.spec);
    const ph::WatchdogParams w;
    c.watchdog_timeout = w.timeoutSeconds;
    c.watchdog_grace = w.graceSeconds;
    c.watchdog_resume = w.resumeSeconds;
}

palp_status palp_session_create_host(palp_scene* scene, const palp_session_params* params,
                                     const palp_device_callbacks* device, palp_session** out) {
    if (!scene) return nullArgument("palp_session_create_host", "scene");
    if (!params) return nullArgument("palp_session_create_host", "params");
    if (!device) return nullArgument("palp_session_create_host", "device");
    if (!device->read_state) {
        return nullArgument("palp_session_create_host", "palp_device_callbacks.read_state");
    }
    if (!out) return nullArgument("palp_session_create_host", "out");
    return guarded([&] {
        const ph::SessionParams sp = toSession(*params);
        checkScenePeriod(*scene, params->period, "palp_session_create_host");
        *out = makeHostSession(scene->scene, sp, *params, *device);
        return PALP_OK;
    });
}

}  // extern "C"
