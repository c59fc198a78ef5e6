#pragma once
/// @file
/// Scene: what a Session can feel (a volume for the volume ray sources, surface meshes for the
/// proxy, hard meshes for the Mesh ray source, optionally a deformable model), and how one is
/// made from a volume (SceneOptions).

#include <limits>
#include <memory>

#include "palp/haptics/tissue/deformable.h"
#include "palp/kernels/embree_scene.h"
#include "palp/kernels/triangle_mesh.h"
#include "palp/kernels/volume_ray.h"
#include "palp/volume/volume.h"

namespace palp::haptics {

/// How a Scene is made from a volume.
struct SceneOptions {
    /// Iso-value (volume units, HU for CT) of the surface the proxy slides on (skin: between
    /// air and fat). NaN: no surface from the volume.
    double surfaceIso = -500;
    /// Iso-value of the hard structures added as hard meshes (mask kMaskBone) for the Mesh ray
    /// source. NaN: none.
    double hardIso = std::numeric_limits<double>::quiet_NaN();
    double adaptivity = 0.0;  ///< volumeToMesh adaptivity for both
};

/// What can be felt: a volume (for the volume ray sources), surface meshes (the proxy's
/// constraints, mask kMaskSurface) and hard meshes (the Mesh ray source).
/// @par Threading  Built on one thread, then immutable and shared (const) by sessions.
class Scene {
  public:
    Scene();
    /// Volume view plus the iso-surfaces of @p options. @throw palp::ValueError.
    static std::shared_ptr<Scene> fromVolume(const volume::Volume& volume,
                                             const SceneOptions& options = {});
    /// Adds a mesh the proxy cannot cross.
    void addSurfaceMesh(const kernels::TriangleMesh& mesh);
    /// Adds a hard structure for the Mesh ray source (mask: kMaskBone, kMaskPlate, ...).
    void addHardMesh(const kernels::TriangleMesh& mesh, unsigned mask = kernels::kMaskBone);
    /// Sets the volume used by the volume ray sources.
    void setVolume(openvdb::FloatGrid::ConstPtr grid);
    /// Commits the Embree scenes; call once after the last add, before a Session uses it.
    void commit();
    /// Makes the scene deformable: every Session builds its own DeformableBody from @p model
    /// and its proxy slides on that body's deformed surface instead of surfaces() (which the
    /// proxy then ignores). AVC/AVCEC rays start from the proxy on the deformed surface and
    /// cast against the static hard meshes, the volume (sampled where the tissue was at rest:
    /// each ray is mapped through the body's displacement, Coupling::setDeformation) and,
    /// with the Mesh source, the model's embedded meshes in their deformed shape. nullptr:
    /// rigid again. @throw nothing.
    void setDeformable(std::shared_ptr<const DeformableModel> model) noexcept {
        mDeformable = std::move(model);
    }
    /// The deformable body's template, or nullptr for a rigid scene.
    const std::shared_ptr<const DeformableModel>& deformable() const noexcept {
        return mDeformable;
    }

    /// The volume of the volume ray sources, or nullptr when none was set.
    const kernels::VolumeView* volumeView() const noexcept { return mView.get(); }
    /// The surfaces the proxy slides on (mask kMaskSurface).
    const kernels::EmbreeScene& surfaces() const noexcept { return *mSurfaces; }
    /// The hard structures of the Mesh ray source.
    const kernels::EmbreeScene& hardMeshes() const noexcept { return *mHard; }

  private:
    std::unique_ptr<kernels::VolumeView> mView;
    std::unique_ptr<kernels::EmbreeScene> mSurfaces, mHard;
    std::shared_ptr<const DeformableModel> mDeformable;
};

}  // namespace palp::haptics
