#include "palp/haptics/scene.h"

#include <openvdb/tools/Count.h>

#include <cmath>
#include <sstream>

#include "palp/base/error.h"
#include "palp/volume/mesh.h"

namespace palp::haptics {
namespace {

// Human-readable "the volume's values span [lo, hi]" for messages about iso-values.
std::string valueRange(const openvdb::FloatGrid& grid) {
    const openvdb::math::MinMax<float> mm = openvdb::tools::minMax(grid.tree());
    std::ostringstream s;
    s << "[" << mm.min() << ", " << mm.max() << "] (background " << grid.background() << ")";
    return s.str();
}

kernels::TriangleMesh isoMesh(const openvdb::FloatGrid& grid, double iso, double adaptivity,
                              const char* what) {
    kernels::TriangleMesh mesh = volume::isoSurface(grid, iso, adaptivity);
    if (mesh.triangleCount() == 0) {
        std::ostringstream s;
        s << "scene: expected the " << what << " iso-value " << iso
          << " to cross the volume's values, found no surface; values span " << valueRange(grid);
        throw ValueError(s.str());
    }
    return mesh;
}

}  // namespace

Scene::Scene()
    : mSurfaces(std::make_unique<kernels::EmbreeScene>(/*robust=*/true)),
      mHard(std::make_unique<kernels::EmbreeScene>()) {}

std::shared_ptr<Scene> Scene::fromVolume(const volume::Volume& volume,
                                         const SceneOptions& options) {
    if (!volume.grid) throw ValueError("scene: expected a volume with a grid, found none");
    if (!(options.adaptivity >= 0.0 && options.adaptivity <= 1.0)) {
        throw ValueError("scene: expected adaptivity in [0, 1], found " +
                         std::to_string(options.adaptivity));
    }
    if (std::isinf(options.surfaceIso) || std::isinf(options.hardIso)) {
        throw ValueError("scene: expected finite iso-values (NaN for none), found surfaceIso " +
                         std::to_string(options.surfaceIso) + ", hardIso " +
                         std::to_string(options.hardIso));
    }
    auto scene = std::make_shared<Scene>();
    scene->setVolume(volume.grid);
    if (!std::isnan(options.surfaceIso)) {
        scene->addSurfaceMesh(
            isoMesh(*volume.grid, options.surfaceIso, options.adaptivity, "surface"));
    }
    if (!std::isnan(options.hardIso)) {
        scene->addHardMesh(isoMesh(*volume.grid, options.hardIso, options.adaptivity, "hard"),
                           kernels::kMaskBone);
    }
    scene->commit();
    return scene;
}

void Scene::addSurfaceMesh(const kernels::TriangleMesh& mesh) {
    mSurfaces->addRigidMesh(mesh, kernels::kMaskSurface);
}

void Scene::addHardMesh(const kernels::TriangleMesh& mesh, unsigned mask) {
    if (mask == 0) throw ValueError("scene: expected a non-zero hard mesh mask, found 0");
    mHard->addRigidMesh(mesh, mask);
}

void Scene::setVolume(openvdb::FloatGrid::ConstPtr grid) {
    if (!grid) throw ValueError("scene: expected a volume grid, found a null pointer");
    mView = std::make_unique<kernels::VolumeView>(std::move(grid));
}

void Scene::commit() {
    // Committing an empty Embree scene is valid and makes tracing it return no hits.
    mSurfaces->commit();
    mHard->commit();
}

}  // namespace palp::haptics
