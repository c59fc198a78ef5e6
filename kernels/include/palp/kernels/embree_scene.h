#pragma once
/// @file
/// An Embree 3 scene of rigid and deforming triangle meshes, and closest-hit tracing of ray
/// bundles against it. Embree stays behind this header: its handles are opaque (forward-declared)
/// and the queries take and return palp types.

#include <Eigen/Core>
#include <array>
#include <cstdint>
#include <memory>
#include <span>
#include <vector>

#include "palp/kernels/ray_bundle.h"
#include "palp/kernels/refit_bvh.h"
#include "palp/kernels/triangle_mesh.h"
#include "palp/kernels/volume_ray.h"

// Embree's handle types (RTCDevice, RTCScene, RTCGeometry are pointers to these), declared here
// so that this header does not include <embree3/rtcore.h>.
struct RTCDeviceTy;
struct RTCSceneTy;
struct RTCGeometryTy;

namespace palp::kernels {

/// Geometry categories as Embree masks: a ray hits a geometry when (ray mask & geometry mask)
/// is non-zero.
inline constexpr unsigned kMaskBone = 1u;
inline constexpr unsigned kMaskPlate = 2u;
inline constexpr unsigned kMaskSurface = 4u;
inline constexpr unsigned kMaskAll = 0xffffffffu;

/// The geometry (and primitive) id of no hit (Embree's RTC_INVALID_GEOMETRY_ID).
inline constexpr unsigned kNoGeometry = 0xffffffffu;

/// Closest hit of one ray (intersectOne()).
struct MeshHit {
    float t = 0;                      ///< hit distance, in units of the ray direction's length
    unsigned geomId = kNoGeometry;    ///< geometry hit (kNoGeometry: none)
    unsigned primId = kNoGeometry;    ///< triangle of that geometry
    float ngX = 0, ngY = 0, ngZ = 0;  ///< geometric normal (not normalised), as Embree reports it
};

namespace detail {
struct RefitUser;  // embree_scene.cpp
}  // namespace detail

/// Owns an RTCScene on palp's one process-wide RTCDevice (created on first use, retained per
/// scene). Add meshes, commit(), then trace.
///
/// @par Threading  Adding geometry, updateVertices() and commit() are for one thread at a time
///      and must not overlap with tracing. Tracing a committed scene is safe from any number of
///      threads at once.
/// @par Real-time  Tracing is real-time safe. updateVertices() is noexcept and copies into
///      Embree's buffer; commit() refits deforming meshes (REFIT quality, O(#T)) but lives in
///      Embree, which may allocate and use TBB: call it on the servo thread only for small
///      meshes and only after measuring (`palp bench rays` prints refit costs). A mesh that
///      deforms every servo tick belongs in addRefitMesh(): its RefitMesh::refit() is
///      allocation-free, about 30x cheaper than Embree's refit commit (bench_refit), and needs
///      no commit; like updateVertices() it must not overlap with tracing.
class EmbreeScene {
  public:
    /// @param robust  RTC_SCENE_FLAG_ROBUST: Embree's watertight traversal, so a ray through a
    ///        shared edge or vertex cannot slip between two triangles (about 10-30 % more per
    ///        ray here). palp's haptics Scene sets it for the surfaces the proxy must never
    ///        cross; the AVC ray targets leave it off.
    /// @throw palp::Error when Embree cannot create the shared device.
    explicit EmbreeScene(bool robust = false);
    ~EmbreeScene();
    EmbreeScene(const EmbreeScene&) = delete;
    EmbreeScene& operator=(const EmbreeScene&) = delete;

    /// Adds a static mesh (high-quality BVH). Returns its geometry id.
    /// @throw palp::ValueError for an empty mesh, indices out of range or non-finite positions.
    unsigned addRigidMesh(const TriangleMesh& mesh, unsigned mask = kMaskAll);
    /// Adds a mesh whose vertices move (refit BVH); topology is fixed. Returns its geometry id.
    /// @throw palp::ValueError as addRigidMesh.
    unsigned addDeformingMesh(const TriangleMesh& mesh, unsigned mask = kMaskAll);
    /// Adds @p mesh as an Embree user geometry traced by palp's own BVH: Embree sees one box,
    /// the mesh's current bounds grown by @p margin metres on every side (the caller's bound on
    /// the deformation), fixed at this call and set as the mesh's limit (RefitMesh::setLimit).
    /// Later mesh.refit() calls need no commit(): the scene is committed once. A refit that
    /// leaves the box reports RefitStatus::OutsideLimit (rays may then miss the parts outside).
    ///
    /// Hits look like triangle hits (primID, u, v, unnormalised Ng, tfar) with the returned
    /// geometry id: that of a disabled triangle geometry sharing the mesh's vertex and index
    /// arrays, so rtcGetGeometryBufferData() on a hit's geomID reads the current triangle as for
    /// any Embree mesh. Honours the ray mask against @p mask, tnear/tfar, every ray count Embree
    /// passes (rtcIntersect1, 1M streams, packets) and rtcOccluded*. Intersection filter
    /// functions are not called.
    ///
    /// @p mesh must outlive the scene and keep its vertex count (refit() does).
    /// @throw palp::ValueError for a negative or non-finite margin; palp::Error from Embree.
    unsigned addRefitMesh(RefitMesh& mesh, unsigned mask, float margin);
    /// Copies new positions (#V by 3, metres) of deforming mesh @p geomId into Embree; takes
    /// effect at the next commit(). Returns false (and changes nothing) for an unknown or rigid
    /// id or a wrong size.
    bool updateVertices(unsigned geomId, std::span<const float> positions) noexcept;
    /// Builds or refits the BVH. @throw palp::Error when Embree reports an error.
    void commit();

    /// The three corners (metres, as stored in Embree's vertex buffer) of triangle @p primId of
    /// geometry @p geomId (a refit mesh's hits name its twin triangle geometry, which shares
    /// the mesh's current arrays). @p primId must be a triangle of the geometry, as a hit
    /// reports it. @return false when the geometry has no vertex or index buffer.
    /// @par Threading  As tracing. @par Real-time  noexcept, no allocation.
    bool triangle(unsigned geomId, unsigned primId,
                  std::array<Eigen::Vector3f, 3>& corners) const noexcept;

    /// The Embree scene (an RTCScene), for benchmarks and tests that compare with raw Embree
    /// calls; palp code uses the queries here.
    RTCSceneTy* handle() const noexcept { return mScene; }
    /// True when no geometry was added.
    bool empty() const noexcept { return mGeoms.empty(); }
    bool committed() const noexcept { return mCommitted; }
    std::size_t triangleCount() const noexcept { return mTriangles; }

  private:
    struct Geom {
        RTCGeometryTy* geometry = nullptr;
        float* vertices = nullptr;  // Embree-owned buffer (deforming meshes)
        std::size_t vertexCount = 0;
        bool deforming = false;
    };
    unsigned add(const TriangleMesh& mesh, unsigned mask, bool deforming);
    RTCDeviceTy* mDevice = nullptr;
    RTCSceneTy* mScene = nullptr;
    std::vector<Geom> mGeoms;                                 // indexed by geometry id
    std::vector<std::unique_ptr<detail::RefitUser>> mRefits;  // user data of refit meshes
    std::size_t mTriangles = 0;
    bool mCommitted = false;
};

/// Closest hit of one ray from @p origin along @p direction (t in units of |direction|) with
/// t in [tnear, tfar], against geometries of @p scene whose mask shares a bit with @p mask
/// (origin and direction rounded to float, as Embree takes them). Fills @p hit when something
/// was hit; else sets hit.geomId to kNoGeometry and leaves the rest.
/// @return whether something was hit
/// @par Threading  Any number of threads on one committed scene.
/// @par Real-time  noexcept, no allocation.
bool intersectOne(const EmbreeScene& scene, const Eigen::Vector3d& origin,
                  const Eigen::Vector3d& direction, float tnear, float tfar, unsigned mask,
                  MeshHit& hit) noexcept;

/// How a bundle is handed to Embree.
enum class MeshTraceMode {
    Loop1,     ///< one rtcIntersect1 per ray
    Stream1M,  ///< one rtcIntersect1M call with the coherent flag
};

/// The mode traceBundle() uses by default (the faster one in bench_rays on x86-64; see
/// bench/README.md).
inline constexpr MeshTraceMode kDefaultMeshTraceMode = MeshTraceMode::Stream1M;

/// Closest hit of every ray of @p bundle against geometries whose mask shares a bit with
/// @p mask. out.t: hit distance (metres) or the ray length; out.hit; out.geomId (or
/// kNoGeometry). An invalid bundle, an empty or uncommitted scene give no hits.
/// @par Threading  Any number of threads on one committed scene, each with its own @p out.
/// @par Real-time  noexcept, no allocation (the ray buffer lives on the stack), no lock.
void traceBundle(const EmbreeScene& scene, const RayBundle& bundle, unsigned mask, BundleHits& out,
                 MeshTraceMode mode = kDefaultMeshTraceMode) noexcept;

}  // namespace palp::kernels
