#pragma once
// Internal to the C API (palp/palp.h): the handles behind its opaque pointers, the error
// plumbing (every exception becomes a status code plus a message) and the C <-> C++
// conversions its files share. c_api.cpp: errors, handles, volumes and scenes;
// c_api_params.cpp: parameter, trajectory and snapshot conversions and defaults;
// c_api_session.cpp: sessions; c_api_deformable.cpp: deformable scenes and their surface;
// c_api_host.cpp: host devices (callbacks behind a watchdog); c_api_udp.cpp: remote devices
// (UdpDevice, the device bridge); c_api_study.cpp: perception studies (palp/palp_study.h).

#include <Eigen/Core>
#include <atomic>
#include <cstring>
#include <exception>
#include <memory>
#include <mutex>
#include <new>
#include <string>
#include <string_view>
#include <type_traits>

#include "palp/base/error.h"
#include "palp/haptics/devices/simulated_device.h"
#include "palp/haptics/devices/trajectory.h"
#include "palp/haptics/devices/udp_device.h"
#include "palp/haptics/devices/watchdog_device.h"
#include "palp/haptics/session.h"
#include "palp/palp.h"
#include "palp/volume/volume.h"

struct palp_volume {
    std::atomic<int> refs{1};
    palp::volume::Volume volume;
};

struct palp_scene {
    std::atomic<int> refs{1};
    std::shared_ptr<const palp::haptics::Scene> scene;
    palp_solver_choice solver{};  // deformable scenes: the solver and why (set at creation)
};

struct palp_session {
    std::atomic<int> refs{1};
    std::string deviceName;          // params.device points here
    palp_session_params params;      // in force; guarded by paramsMutex (producer and controller)
    mutable std::mutex paramsMutex;  // never taken by the servo thread
    std::unique_ptr<palp::haptics::Device> device;            // simulated, or the host's callbacks
    std::unique_ptr<palp::haptics::WatchdogDevice> watchdog;  // host devices: around device
    palp::haptics::UdpDevice* udp = nullptr;          // remote devices: device, as what it is
    std::unique_ptr<palp::haptics::Session> session;  // declared last: destroyed (stopped) first
    ~palp_session() { session.reset(); }
};

namespace palp::capi {

// --- errors and handles (c_api.cpp) ----------------------------------------------------

/// Records @p message as the calling thread's last error, calls the error callback and
/// returns @p status.
palp_status fail(palp_status status, const char* message) noexcept;

/// fail(PALP_ERROR_INVALID_ARGUMENT, "<function>: expected a non-NULL <argument>, found NULL").
palp_status nullArgument(const char* function, const char* argument) noexcept;

/// Runs @p body, mapping every exception to a status (the only place exceptions stop).
template <typename Body>
palp_status guarded(Body&& body) noexcept {
    try {
        return body();
    } catch (const palp::ValueError& e) {
        return fail(PALP_ERROR_INVALID_ARGUMENT, e.what());
    } catch (const palp::IoError& e) {
        return fail(PALP_ERROR_IO, e.what());
    } catch (const palp::FormatError& e) {
        return fail(PALP_ERROR_FORMAT, e.what());
    } catch (const std::bad_alloc&) {
        return fail(PALP_ERROR_OUT_OF_MEMORY, "palp: out of memory");
    } catch (const std::exception& e) {
        return fail(PALP_ERROR_INTERNAL, e.what());
    } catch (...) {
        return fail(PALP_ERROR_INTERNAL, "palp: unknown exception");
    }
}

template <typename Handle>
Handle* retain(Handle* h) noexcept {
    if (h) h->refs.fetch_add(1, std::memory_order_relaxed);
    return h;
}

template <typename Handle>
void release(Handle* h) noexcept {
    // acq_rel: the last owner sees every other owner's writes before deleting.
    if (h && h->refs.fetch_sub(1, std::memory_order_acq_rel) == 1) delete h;
}

/// The integer a C caller stored in an enum field or parameter, read from its bytes: a C enum
/// may hold any int, but loading a value outside the enumerators as the enum type is undefined
/// in C++ (UBSan's -fsanitize=enum), so palp never loads one before it is checked.
template <typename E>
int rawEnum(const E& e) noexcept {
    static_assert(std::is_enum_v<E>);
    std::underlying_type_t<E> v;
    std::memcpy(&v, &e, sizeof v);
    return static_cast<int>(v);
}

inline Eigen::Vector3d vec(const double v[3]) { return Eigen::Vector3d(v[0], v[1], v[2]); }
inline void put(const Eigen::Vector3d& v, double out[3]) noexcept {
    out[0] = v.x();
    out[1] = v.y();
    out[2] = v.z();
}

// --- conversions (c_api_params.cpp); each @throw palp::ValueError naming the C field --------

const haptics::DeviceSpec& deviceSpec(const char* name);
haptics::CouplingParams toCoupling(const palp_session_params& p);
haptics::ProxyParams toProxy(const palp_session_params& p);
haptics::SessionParams toSession(const palp_session_params& p);
/// C++ -> C: @p d's fields that palp_session_params holds (device "3D Systems Touch X", the
/// accumulate hardness 1e4 /m: a step the C struct can express; callers set what differs).
void fromSession(const haptics::SessionParams& d, palp_session_params& p) noexcept;
/// The fields a running session cannot change; the first that differs, or nullptr.
const char* fixedFieldChanged(const palp_session_params& a, const palp_session_params& b);
haptics::Trajectory toTrajectory(const palp_trajectory& c);
haptics::HandModel toHand(const palp_trajectory& c);
void toC(const haptics::Snapshot& s, palp_snapshot& c) noexcept;
/// The servo period a deformable scene's body was made for, s (0 for a rigid scene).
double deformablePeriod(const palp_scene& scene) noexcept;
/// @throw palp::ValueError naming @p function's palp_session_params.period when @p scene is
/// deformable and made for another period.
void checkScenePeriod(const palp_scene& scene, double period, const char* function);
palp_latency toC(const haptics::LatencySummary& l) noexcept;

// --- device specs and watchdogs of host and remote devices (c_api_host.cpp) ---------------

/// C -> C++, checking every field. @throw palp::ValueError naming the C field
/// ("<owner>.spec.max_force").
haptics::DeviceSpec toSpec(const palp_device_spec& c, std::string_view name, const char* owner);
/// @throw palp::ValueError naming "<owner>.watchdog_timeout/_grace/_resume".
haptics::WatchdogParams toWatchdog(double timeout, double grace, double resume, const char* owner);
void fromSpec(const haptics::DeviceSpec& s, palp_device_spec& c) noexcept;
/// The session's fault ramp with the device watchdog's times (so a bad sample ramps alike in
/// both; the force-step limit keeps its default).
haptics::FaultParams faultsLike(const haptics::WatchdogParams& w) noexcept;
/// A session on the host's @p device (its spec and watchdog checked, the session's fault ramp
/// as the watchdog's) with @p sp; @p cParams is what palp_session_get_params reports.
/// @throw palp::ValueError naming the C field.
palp_session* makeHostSession(std::shared_ptr<const haptics::Scene> scene,
                              haptics::SessionParams sp, const palp_session_params& cParams,
                              const palp_device_callbacks& device);

}  // namespace palp::capi
