// The C API (palp/palp.h): a thin layer over palp::haptics that converts plain C structs,
// counts references and turns every exception into a status code plus a message. This file:
// errors, handles, volumes and scenes (see c_api_internal.h for the others).

#include <cmath>
#include <cstring>
#include <filesystem>
#include <memory>
#include <mutex>
#include <string>

#include "c_api_internal.h"
#include "palp/base/bounds.h"
#include "palp/base/validate.h"
#include "palp/volume/from_memory.h"
#include "palp/volume/load.h"
#include "palp/volume/phantom.h"

namespace ph = palp::haptics;
namespace pv = palp::volume;

namespace palp::capi {
namespace {

thread_local std::string tLastError;

std::mutex gCallbackMutex;  // guards the two below (set rarely, read on failures only)
palp_error_callback gCallback = nullptr;
void* gCallbackUser = nullptr;

}  // namespace

palp_status fail(palp_status status, const char* message) noexcept {
    try {
        tLastError = message;
    } catch (...) {
        tLastError.clear();  // no memory for the message: an empty one is still valid
    }
    palp_error_callback cb = nullptr;
    void* user = nullptr;
    {
        std::lock_guard<std::mutex> lock(gCallbackMutex);
        cb = gCallback;
        user = gCallbackUser;
    }
    if (cb) cb(user, status, tLastError.c_str());
    return status;
}

palp_status nullArgument(const char* function, const char* argument) noexcept {
    std::string m;
    try {
        m = std::string(function) + ": expected a non-NULL " + argument + ", found NULL";
    } catch (...) {
    }
    return fail(PALP_ERROR_INVALID_ARGUMENT, m.c_str());
}

}  // namespace palp::capi

using namespace palp::capi;

extern "C" {

const char* palp_version(void) { return "0.1.0"; }

const char* palp_status_string(palp_status status) {
    switch (status) {
        case PALP_OK:
            return "PALP_OK";
        case PALP_ERROR_INVALID_ARGUMENT:
            return "PALP_ERROR_INVALID_ARGUMENT";
        case PALP_ERROR_IO:
            return "PALP_ERROR_IO";
        case PALP_ERROR_FORMAT:
            return "PALP_ERROR_FORMAT";
        case PALP_ERROR_STATE:
            return "PALP_ERROR_STATE";
        case PALP_ERROR_QUEUE_FULL:
            return "PALP_ERROR_QUEUE_FULL";
        case PALP_ERROR_OUT_OF_MEMORY:
            return "PALP_ERROR_OUT_OF_MEMORY";
        case PALP_ERROR_REALTIME:
            return "PALP_ERROR_REALTIME";
        case PALP_ERROR_INTERNAL:
            return "PALP_ERROR_INTERNAL";
    }
    return "PALP_ERROR_UNKNOWN";
}

const char* palp_last_error(void) { return palp::capi::tLastError.c_str(); }

void palp_set_error_callback(palp_error_callback callback, void* user) {
    std::lock_guard<std::mutex> lock(palp::capi::gCallbackMutex);
    palp::capi::gCallback = callback;
    palp::capi::gCallbackUser = user;
}

// --- volumes ---------------------------------------------------------------------------

palp_status palp_volume_load(const char* path, double voxel_size, palp_volume** out) {
    if (!path) return nullArgument("palp_volume_load", "path");
    if (!out) return nullArgument("palp_volume_load", "out");
    return guarded([&] {
        // 0 asks for the default (the finest input spacing); anything else is a voxel edge.
        if (voxel_size != 0) {
            palp::requireWithin("palp_volume_load: voxel_size (0: the finest input spacing)",
                                voxel_size, palp::bounds::kSpacing);
        }
        pv::LoadOptions options;
        if (voxel_size > 0) options.resample.voxelSize = voxel_size;
        auto handle = std::make_unique<palp_volume>();
        handle->volume = pv::load({std::filesystem::path(path)}, options);
        *out = handle.release();
        return PALP_OK;
    });
}

palp_status palp_volume_make_phantom(const char* scene, int variant, const char* shape,
                                     double voxel_size, palp_volume** out) {
    if (!scene) return nullArgument("palp_volume_make_phantom", "scene");
    if (!out) return nullArgument("palp_volume_make_phantom", "out");
    return guarded([&] {
        pv::PhantomSpec spec;
        spec.params.scene = pv::parseScene(scene);
        if (spec.params.scene == pv::PhantomScene::Avc) spec.params.quadrant = variant;
        if (spec.params.scene == pv::PhantomScene::Bone) spec.params.displacement = variant;
        if (spec.params.scene == pv::PhantomScene::Avcec && shape) {
            spec.params.shape = pv::parseShape(shape);
        }
        palp::requireWithin("palp_volume_make_phantom: voxel_size", voxel_size,
                            palp::bounds::kSpacing);
        spec.voxelSize = voxel_size;
        auto handle = std::make_unique<palp_volume>();
        handle->volume = pv::makePhantomVolume(spec);
        *out = handle.release();
        return PALP_OK;
    });
}

palp_status palp_volume_from_memory(const void* data, palp_value_type type, const int64_t dims[3],
                                    const int64_t strides[3], const double index_to_world[16],
                                    palp_world_frame frame, double voxel_size, palp_volume** out) {
    constexpr const char* kName = "palp_volume_from_memory";
    if (!data) return nullArgument(kName, "data");
    if (!dims) return nullArgument(kName, "dims");
    if (!index_to_world) return nullArgument(kName, "index_to_world");
    if (!out) return nullArgument(kName, "out");
    return guarded([&] {
        const int t = rawEnum(type);
        if (t < PALP_VALUE_I8 || t > PALP_VALUE_F64) {
            palp::throwExpected(std::string(kName) + ": type",
                                "PALP_VALUE_I8 .. PALP_VALUE_F64 (0..7)", std::to_string(t));
        }
        const int f = rawEnum(frame);
        if (f < PALP_FRAME_LPS_M || f > PALP_FRAME_RAS_MM) {
            palp::throwExpected(std::string(kName) + ": frame",
                                "PALP_FRAME_LPS_M, _RAS_M, _LPS_MM or _RAS_MM (0..3)",
                                std::to_string(f));
        }
        if (voxel_size != 0) {
            palp::requireWithin(std::string(kName) + ": voxel_size (0: the finest spacing)",
                                voxel_size, palp::bounds::kSpacing);
        }
        pv::MemoryGrid g;
        g.data = data;
        g.type = static_cast<pv::ValueType>(t);  // same order as palp_value_type
        g.frame = static_cast<pv::WorldFrame>(f);
        for (int a = 0; a < 3; ++a) {
            g.dims[static_cast<std::size_t>(a)] = dims[a];
            g.strides[static_cast<std::size_t>(a)] = strides ? strides[a] : 0;
        }
        for (int r = 0; r < 4; ++r) {
            for (int c = 0; c < 4; ++c) g.indexToWorld(r, c) = index_to_world[4 * r + c];
        }
        g.name = kName;
        pv::ResampleOptions options;
        if (voxel_size > 0) options.voxelSize = voxel_size;
        auto handle = std::make_unique<palp_volume>();
        handle->volume = pv::fromMemory(g, options);
        *out = handle.release();
        return PALP_OK;
    });
}

palp_status palp_volume_geometry(const palp_volume* volume, double* voxel_size,
                                 double bounds_min[3], double bounds_max[3]) {
    if (!volume) return nullArgument("palp_volume_geometry", "volume");
    return guarded([&] {
        if (voxel_size) *voxel_size = volume->volume.voxelSize();
        const openvdb::BBoxd b = volume->volume.worldBounds();
        for (int i = 0; i < 3; ++i) {
            if (bounds_min) bounds_min[i] = b.min()[i];
            if (bounds_max) bounds_max[i] = b.max()[i];
        }
        return PALP_OK;
    });
}

palp_volume* palp_volume_retain(palp_volume* volume) { return retain(volume); }
void palp_volume_release(palp_volume* volume) { release(volume); }

// --- scenes ----------------------------------------------------------------------------

palp_status palp_scene_from_volume(const palp_volume* volume, double surface_iso, double hard_iso,
                                   palp_scene** out) {
    if (!volume) return nullArgument("palp_scene_from_volume", "volume");
    if (!out) return nullArgument("palp_scene_from_volume", "out");
    return guarded([&] {
        // NAN leaves the iso-surface out (as documented); anything else must be a value.
        if (!std::isnan(surface_iso)) {
            palp::requireWithin("palp_scene_from_volume: surface_iso (NAN: none)", surface_iso,
                                palp::bounds::kVolumeValue);
        }
        if (!std::isnan(hard_iso)) {
            palp::requireWithin("palp_scene_from_volume: hard_iso (NAN: none)", hard_iso,
                                palp::bounds::kVolumeValue);
        }
        ph::SceneOptions options;
        options.surfaceIso = surface_iso;
        options.hardIso = hard_iso;
        auto handle = std::make_unique<palp_scene>();
        handle->scene = ph::Scene::fromVolume(volume->volume, options);
        *out = handle.release();
        return PALP_OK;
    });
}

palp_status palp_scene_create_empty(palp_scene** out) {
    if (!out) return nullArgument("palp_scene_create_empty", "out");
    return guarded([&] {
        auto scene = std::make_shared<ph::Scene>();
        scene->commit();
        auto handle = std::make_unique<palp_scene>();
        handle->scene = std::move(scene);
        *out = handle.release();
        return PALP_OK;
    });
}

palp_scene* palp_scene_retain(palp_scene* scene) { return retain(scene); }
void palp_scene_release(palp_scene* scene) { release(scene); }

}  // extern "C"
