#include "palp/kernels/embree_scene.h"

#include <embree3/rtcore.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstring>
#include <limits>
#include <string>

#include "palp/base/error.h"
#include "palp/base/validate.h"

namespace palp::kernels {

static_assert(kNoGeometry == RTC_INVALID_GEOMETRY_ID);

namespace {

void checkMesh(const TriangleMesh& m) {
    if (m.triangleCount() == 0 || m.positions.size() % 3 != 0 || m.indices.size() % 3 != 0)
        throwExpected("mesh", "at least one triangle and 3 floats per vertex",
                      std::to_string(m.positions.size()) + " position floats and " +
                          std::to_string(m.indices.size()) + " indices");
    const std::size_t nv = m.vertexCount();
    for (std::size_t i = 0; i < m.indices.size(); ++i)
        if (m.indices[i] >= nv)
            throwExpected("mesh index " + std::to_string(i), "< " + std::to_string(nv),
                          std::to_string(m.indices[i]));
    for (std::size_t i = 0; i < m.positions.size(); ++i)
        if (!std::isfinite(m.positions[i]))
            throwExpected("mesh position " + std::to_string(i / 3), "finite coordinates",
                          formatValue(static_cast<double>(m.positions[i])));
}

void errorCallback(void*, RTCError, const char*) {}

/// One Embree device for the whole process, created on first use and never released. Every
/// device brings up and tears down Embree's tasking state on top of TBB; creating one per scene
/// (hundreds in the refit benchmark) churned that state while TBB workers from the previous
/// build were still winding down, and cost a millisecond per scene. Devices are thread-safe
/// for creating scenes; Embree keeps error codes per thread.
RTCDevice sharedDevice() {
    static const RTCDevice device = [] {
        RTCDevice d = rtcNewDevice(nullptr);
        if (d) rtcSetDeviceErrorFunction(d, errorCallback, nullptr);
        return d;
    }();
    return device;
}

}  // namespace

EmbreeScene::EmbreeScene(bool robust) {
    mDevice = sharedDevice();
    if (!mDevice)
        throw Error("embree: expected a device, found rtcNewDevice error " +
                    std::to_string(static_cast<int>(rtcGetDeviceError(nullptr))));
    rtcRetainDevice(mDevice);
    mScene = rtcNewScene(mDevice);
    rtcSetSceneFlags(
        mScene, robust ? (RTC_SCENE_FLAG_DYNAMIC | RTC_SCENE_FLAG_ROBUST) : RTC_SCENE_FLAG_DYNAMIC);
    rtcSetSceneBuildQuality(mScene, RTC_BUILD_QUALITY_MEDIUM);
}

EmbreeScene::~EmbreeScene() {
    if (mScene) rtcReleaseScene(mScene);
    if (mDevice) rtcReleaseDevice(mDevice);
}

unsigned EmbreeScene::add(const TriangleMesh& mesh, unsigned mask, bool deforming) {
    checkMesh(mesh);
    RTCGeometry g = rtcNewGeometry(mDevice, RTC_GEOMETRY_TYPE_TRIANGLE);
    auto* v = static_cast<float*>(rtcSetNewGeometryBuffer(
        g, RTC_BUFFER_TYPE_VERTEX, 0, RTC_FORMAT_FLOAT3, 3 * sizeof(float), mesh.vertexCount()));
    auto* idx = static_cast<std::uint32_t*>(
        rtcSetNewGeometryBuffer(g, RTC_BUFFER_TYPE_INDEX, 0, RTC_FORMAT_UINT3,
                                3 * sizeof(std::uint32_t), mesh.triangleCount()));
    if (!v || !idx) {
        rtcReleaseGeometry(g);
        throw Error("embree: expected geometry buffers, found an allocation failure");
    }
    std::memcpy(v, mesh.positions.data(), mesh.positions.size() * sizeof(float));
    std::memcpy(idx, mesh.indices.data(), mesh.indices.size() * sizeof(std::uint32_t));
    rtcSetGeometryMask(g, mask);
    rtcSetGeometryBuildQuality(g, deforming ? RTC_BUILD_QUALITY_REFIT : RTC_BUILD_QUALITY_HIGH);
    rtcCommitGeometry(g);
    const unsigned id = rtcAttachGeometry(mScene, g);
    rtcReleaseGeometry(g);  // the scene holds it
    if (mGeoms.size() <= id) mGeoms.resize(id + 1);
    mGeoms[id] = Geom{g, v, mesh.vertexCount(), deforming};
    mTriangles += mesh.triangleCount();
    mCommitted = false;
    return id;
}

unsigned EmbreeScene::addRigidMesh(const TriangleMesh& mesh, unsigned mask) {
    return add(mesh, mask, false);
}
unsigned EmbreeScene::addDeformingMesh(const TriangleMesh& mesh, unsigned mask) {
    return add(mesh, mask, true);
}

namespace detail {
/// What the user-geometry callbacks see (a stable address owned by the scene).
struct RefitUser {
    const RefitMesh* mesh = nullptr;
    unsigned mask = 0;
    unsigned reportId = 0;  // the twin triangle geometry's id
};
}  // namespace detail

namespace {

void refitBounds(const RTCBoundsFunctionArguments* args) {
    const auto* user = static_cast<const detail::RefitUser*>(args->geometryUserPtr);
    const Box3f& b = user->mesh->limit();
    args->bounds_o->lower_x = b.lo[0];
    args->bounds_o->lower_y = b.lo[1];
    args->bounds_o->lower_z = b.lo[2];
    args->bounds_o->upper_x = b.hi[0];
    args->bounds_o->upper_y = b.hi[1];
    args->bounds_o->upper_z = b.hi[2];
}

std::array<float, 3> rayOrigin(RTCRayN* ray, unsigned n, unsigned i) {
    return {RTCRayN_org_x(ray, n, i), RTCRayN_org_y(ray, n, i), RTCRayN_org_z(ray, n, i)};
}

std::array<float, 3> rayDirection(RTCRayN* ray, unsigned n, unsigned i) {
    return {RTCRayN_dir_x(ray, n, i), RTCRayN_dir_y(ray, n, i), RTCRayN_dir_z(ray, n, i)};
}

void refitIntersect(const RTCIntersectFunctionNArguments* args) {
    const auto* user = static_cast<const detail::RefitUser*>(args->geometryUserPtr);
    const unsigned n = args->N;
    RTCRayN* ray = RTCRayHitN_RayN(args->rayhit, n);
    RTCHitN* hit = RTCRayHitN_HitN(args->rayhit, n);
    for (unsigned i = 0; i < n; ++i) {
        if (args->valid[i] == 0) continue;
        if ((RTCRayN_mask(ray, n, i) & user->mask) == 0) continue;
        const std::array<float, 3> org = rayOrigin(ray, n, i), dir = rayDirection(ray, n, i);
        TriangleHit h;
        if (!user->mesh->intersect(org, dir, RTCRayN_tnear(ray, n, i), RTCRayN_tfar(ray, n, i), h))
            continue;
        RTCRayN_tfar(ray, n, i) = h.t;
        RTCHitN_Ng_x(hit, n, i) = h.ng[0];
        RTCHitN_Ng_y(hit, n, i) = h.ng[1];
        RTCHitN_Ng_z(hit, n, i) = h.ng[2];
        RTCHitN_u(hit, n, i) = h.u;
        RTCHitN_v(hit, n, i) = h.v;
        RTCHitN_primID(hit, n, i) = h.primId;
        RTCHitN_geomID(hit, n, i) = user->reportId;
        for (unsigned l = 0; l < RTC_MAX_INSTANCE_LEVEL_COUNT; ++l)
            RTCHitN_instID(hit, n, i, l) = args->context->instID[l];
    }
}

void refitOccluded(const RTCOccludedFunctionNArguments* args) {
    const auto* user = static_cast<const detail::RefitUser*>(args->geometryUserPtr);
    const unsigned n = args->N;
    RTCRayN* ray = args->ray;
    for (unsigned i = 0; i < n; ++i) {
        if (args->valid[i] == 0) continue;
        if ((RTCRayN_mask(ray, n, i) & user->mask) == 0) continue;
        const std::array<float, 3> org = rayOrigin(ray, n, i), dir = rayDirection(ray, n, i);
        if (user->mesh->occluded(org, dir, RTCRayN_tnear(ray, n, i), RTCRayN_tfar(ray, n, i)))
            RTCRayN_tfar(ray, n, i) = -std::numeric_limits<float>::infinity();
    }
}

}  // namespace

unsigned EmbreeScene::addRefitMesh(RefitMesh& mesh, unsigned mask, float margin) {
    requireNonNegative("refit mesh margin", static_cast<double>(margin), "m");
    Box3f limit = mesh.bounds();
    for (std::size_t k = 0; k < 3; ++k) {
        limit.lo[k] -= margin;
        limit.hi[k] += margin;
    }
    mesh.setLimit(limit);

    // The twin: a disabled triangle geometry (never traversed) that shares the mesh's arrays,
    // so a hit's geometry id leads to the current vertices as for any Embree mesh.
    RTCGeometry twin = rtcNewGeometry(mDevice, RTC_GEOMETRY_TYPE_TRIANGLE);
    rtcSetSharedGeometryBuffer(twin, RTC_BUFFER_TYPE_VERTEX, 0, RTC_FORMAT_FLOAT3,
                               mesh.positions().data(), 0, 3 * sizeof(float), mesh.vertexCount());
    rtcSetSharedGeometryBuffer(twin, RTC_BUFFER_TYPE_INDEX, 0, RTC_FORMAT_UINT3,
                               mesh.indices().data(), 0, 3 * sizeof(std::uint32_t),
                               mesh.triangleCount());
    rtcSetGeometryMask(twin, 0);
    rtcCommitGeometry(twin);
    const unsigned twinId = rtcAttachGeometry(mScene, twin);
    rtcDisableGeometry(twin);
    rtcReleaseGeometry(twin);

    auto user = std::make_unique<detail::RefitUser>();
    user->mesh = &mesh;
    user->mask = mask;
    user->reportId = twinId;
    RTCGeometry g = rtcNewGeometry(mDevice, RTC_GEOMETRY_TYPE_USER);
    rtcSetGeometryUserPrimitiveCount(g, 1);
    rtcSetGeometryUserData(g, user.get());
    rtcSetGeometryBoundsFunction(g, refitBounds, user.get());
    rtcSetGeometryIntersectFunction(g, refitIntersect);
    rtcSetGeometryOccludedFunction(g, refitOccluded);
    rtcSetGeometryMask(g, mask);
    rtcCommitGeometry(g);
    const unsigned id = rtcAttachGeometry(mScene, g);
    rtcReleaseGeometry(g);
    const RTCError e = rtcGetDeviceError(mDevice);
    if (e != RTC_ERROR_NONE) {
        // Nothing may keep pointing at `user` (freed on the way out) or at the caller's mesh.
        if (id != RTC_INVALID_GEOMETRY_ID) rtcDetachGeometry(mScene, id);
        if (twinId != RTC_INVALID_GEOMETRY_ID) rtcDetachGeometry(mScene, twinId);
        throw Error("embree user geometry: expected no error, found error code " +
                    std::to_string(static_cast<int>(e)));
    }
    mRefits.push_back(std::move(user));
    if (mGeoms.size() <= std::max(id, twinId)) mGeoms.resize(std::max(id, twinId) + 1);
    mGeoms[twinId] = Geom{twin, nullptr, mesh.vertexCount(), false};
    mGeoms[id] = Geom{g, nullptr, 0, false};
    mTriangles += mesh.triangleCount();
    mCommitted = false;
    return twinId;
}

bool EmbreeScene::updateVertices(unsigned geomId, std::span<const float> positions) noexcept {
    if (geomId >= mGeoms.size()) return false;
    Geom& g = mGeoms[geomId];
    if (!g.deforming || !g.geometry || positions.size() != 3 * g.vertexCount) return false;
    std::memcpy(g.vertices, positions.data(), positions.size_bytes());
    rtcUpdateGeometryBuffer(g.geometry, RTC_BUFFER_TYPE_VERTEX, 0);
    rtcCommitGeometry(g.geometry);
    return true;
}

void EmbreeScene::commit() {
    rtcCommitScene(mScene);
    const RTCError e = rtcGetDeviceError(mDevice);
    if (e != RTC_ERROR_NONE)
        throw Error("embree scene commit: expected no error, found error code " +
                    std::to_string(static_cast<int>(e)));
    mCommitted = true;
}

bool EmbreeScene::triangle(unsigned geomId, unsigned primId,
                           std::array<Eigen::Vector3f, 3>& corners) const noexcept {
    RTCGeometry g = rtcGetGeometry(mScene, geomId);
    if (!g) return false;
    const auto* v =
        static_cast<const float*>(rtcGetGeometryBufferData(g, RTC_BUFFER_TYPE_VERTEX, 0));
    const auto* idx =
        static_cast<const std::uint32_t*>(rtcGetGeometryBufferData(g, RTC_BUFFER_TYPE_INDEX, 0));
    if (!v || !idx) return false;
    const std::size_t t = 3 * static_cast<std::size_t>(primId);
    for (std::size_t k = 0; k < 3; ++k) {
        const std::size_t i = 3 * static_cast<std::size_t>(idx[t + k]);
        corners[k] = Eigen::Vector3f(v[i], v[i + 1], v[i + 2]);
    }
    return true;
}

bool intersectOne(const EmbreeScene& scene, const Eigen::Vector3d& origin,
                  const Eigen::Vector3d& direction, float tnear, float tfar, unsigned mask,
                  MeshHit& hit) noexcept {
    alignas(16) RTCRayHit rh;
    RTCIntersectContext ctx;
    rtcInitIntersectContext(&ctx);
    rh.ray.org_x = static_cast<float>(origin.x());
    rh.ray.org_y = static_cast<float>(origin.y());
    rh.ray.org_z = static_cast<float>(origin.z());
    rh.ray.dir_x = static_cast<float>(direction.x());
    rh.ray.dir_y = static_cast<float>(direction.y());
    rh.ray.dir_z = static_cast<float>(direction.z());
    rh.ray.tnear = tnear;
    rh.ray.tfar = tfar;
    rh.ray.time = 0.0f;
    rh.ray.mask = mask;
    rh.ray.id = 0;
    rh.ray.flags = 0;
    rh.hit.geomID = RTC_INVALID_GEOMETRY_ID;
    rh.hit.instID[0] = RTC_INVALID_GEOMETRY_ID;
    rtcIntersect1(scene.handle(), &ctx, &rh);
    hit.geomId = rh.hit.geomID;
    if (rh.hit.geomID == RTC_INVALID_GEOMETRY_ID) return false;
    hit.t = rh.ray.tfar;
    hit.primId = rh.hit.primID;
    hit.ngX = rh.hit.Ng_x;
    hit.ngY = rh.hit.Ng_y;
    hit.ngZ = rh.hit.Ng_z;
    return true;
}

namespace {

inline void setRay(RTCRayHit& rh, const RayBundle& b, std::size_t r, unsigned mask) noexcept {
    rh.ray.org_x = b.ox[r];
    rh.ray.org_y = b.oy[r];
    rh.ray.org_z = b.oz[r];
    rh.ray.dir_x = b.dx[r];
    rh.ray.dir_y = b.dy[r];
    rh.ray.dir_z = b.dz[r];
    rh.ray.tnear = 0.0f;
    const float len = b.length[r];
    rh.ray.tfar = std::isfinite(len) && len >= 0 ? len : 0.0f;
    rh.ray.time = 0.0f;
    rh.ray.mask = mask;
    rh.ray.id = static_cast<unsigned>(r);
    rh.ray.flags = 0;
    rh.hit.geomID = RTC_INVALID_GEOMETRY_ID;
    rh.hit.instID[0] = RTC_INVALID_GEOMETRY_ID;
}

inline void takeHit(const RTCRayHit& rh, const RayBundle& b, std::size_t r,
                    BundleHits& out) noexcept {
    const bool hit = rh.hit.geomID != RTC_INVALID_GEOMETRY_ID;
    out.hit[r] = hit ? 1 : 0;
    out.t[r] = hit ? rh.ray.tfar : b.length[r];
    out.geomId[r] = rh.hit.geomID;
}

}  // namespace

void traceBundle(const EmbreeScene& scene, const RayBundle& bundle, unsigned mask, BundleHits& out,
                 MeshTraceMode mode) noexcept {
    out.count = bundle.valid ? std::clamp(bundle.count, 0, kMaxBundleRays) : 0;
    if (scene.empty() || !scene.committed()) {
        for (int i = 0; i < out.count; ++i) {
            const auto r = static_cast<std::size_t>(i);
            out.hit[r] = 0;
            out.t[r] = bundle.length[r];
            out.geomId[r] = RTC_INVALID_GEOMETRY_ID;
        }
        return;
    }
    RTCIntersectContext ctx;
    rtcInitIntersectContext(&ctx);
    if (mode == MeshTraceMode::Loop1) {
        for (int i = 0; i < out.count; ++i) {
            const auto r = static_cast<std::size_t>(i);
            alignas(16) RTCRayHit rh;
            setRay(rh, bundle, r, mask);
            rtcIntersect1(scene.handle(), &ctx, &rh);
            takeHit(rh, bundle, r, out);
        }
        return;
    }
    ctx.flags = RTC_INTERSECT_CONTEXT_FLAG_COHERENT;
    alignas(16) std::array<RTCRayHit, kMaxBundleRays> rays;
    for (int i = 0; i < out.count; ++i)
        setRay(rays[static_cast<std::size_t>(i)], bundle, static_cast<std::size_t>(i), mask);
    rtcIntersect1M(scene.handle(), &ctx, rays.data(), static_cast<unsigned>(out.count),
                   sizeof(RTCRayHit));
    for (int i = 0; i < out.count; ++i)
        takeHit(rays[static_cast<std::size_t>(i)], bundle, static_cast<std::size_t>(i), out);
}

}  // namespace palp::kernels
