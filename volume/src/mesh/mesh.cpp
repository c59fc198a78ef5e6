#include "palp/volume/mesh.h"

#include <assimp/postprocess.h>
#include <assimp/scene.h>
#include <openvdb/tools/VolumeToMesh.h>

#include <assimp/Importer.hpp>
#include <cmath>
#include <fstream>
#include <string>

#include "palp/base/bounds.h"
#include "palp/base/error.h"
#include "vdb/vdb_errors.h"

namespace palp::volume {

TriangleMesh loadMesh(const std::filesystem::path& path, double metresPerUnit) {
    if (!(std::isfinite(metresPerUnit) && metresPerUnit > 0))
        throw ValueError(path.string() + ": expected a unit scale > 0 m, found " +
                         std::to_string(metresPerUnit));
    std::error_code ec;
    if (!std::filesystem::is_regular_file(path, ec))
        throw IoError(path.string() + ": expected a readable mesh file, found none");
    Assimp::Importer importer;
    const aiScene* scene =
        importer.ReadFile(path.string(), aiProcess_Triangulate | aiProcess_JoinIdenticalVertices |
                                             aiProcess_SortByPType);
    if (!scene || !scene->mRootNode)
        throw FormatError(
            path.string() +
            ": expected a mesh file (OBJ, STL, PLY, ...), found an unreadable file (" +
            importer.GetErrorString() + ")");
    TriangleMesh out;
    for (unsigned m = 0; m < scene->mNumMeshes; ++m) {
        const aiMesh* mesh = scene->mMeshes[m];
        const auto base = static_cast<std::uint32_t>(out.vertexCount());
        for (unsigned v = 0; v < mesh->mNumVertices; ++v) {
            const aiVector3D& p = mesh->mVertices[v];
            out.positions.push_back(static_cast<float>(p.x * metresPerUnit));
            out.positions.push_back(static_cast<float>(p.y * metresPerUnit));
            out.positions.push_back(static_cast<float>(p.z * metresPerUnit));
        }
        for (unsigned f = 0; f < mesh->mNumFaces; ++f) {
            const aiFace& face = mesh->mFaces[f];
            if (face.mNumIndices != 3) continue;  // points and lines
            for (unsigned k = 0; k < 3; ++k) out.indices.push_back(base + face.mIndices[k]);
        }
    }
    if (out.triangleCount() == 0)
        throw FormatError(path.string() + ": expected triangles, found none");
    return out;
}

TriangleMesh isoSurface(const openvdb::FloatGrid& grid, double isoValue, double adaptivity) {
    palp::requireWithin("iso-surface value", isoValue, bounds::kVolumeValue);
    palp::requireWithin("iso-surface grid background", static_cast<double>(grid.background()),
                        bounds::kVolumeValue);
    if (!(adaptivity >= 0 && adaptivity <= 1))
        throw ValueError("iso-surface adaptivity: expected a value in [0, 1], found " +
                         std::to_string(adaptivity));
    std::vector<openvdb::Vec3s> points;
    std::vector<openvdb::Vec3I> tris;
    std::vector<openvdb::Vec4I> quads;
    // OpenVDB refuses NaN voxels ("VolumeToMesh encountered NaNs") and singular transforms in
    // its own words; the caller learns it is this grid's values or transform.
    detail::withVdbErrors<ValueError>(
        "iso-surface grid", "finite voxel values and an invertible transform",
        [&] { openvdb::tools::volumeToMesh(grid, points, tris, quads, isoValue, adaptivity); });
    TriangleMesh out;
    out.positions.reserve(points.size() * 3);
    for (const auto& p : points) {
        out.positions.push_back(p.x());
        out.positions.push_back(p.y());
        out.positions.push_back(p.z());
    }
    out.indices.reserve(tris.size() * 3 + quads.size() * 6);
    for (const auto& t : tris)
        for (int k = 0; k < 3; ++k) out.indices.push_back(t[k]);
    for (const auto& q : quads) {
        for (int k : {0, 1, 2}) out.indices.push_back(q[k]);
        for (int k : {0, 2, 3}) out.indices.push_back(q[k]);
    }
    return out;
}

void saveObj(const TriangleMesh& mesh, const std::filesystem::path& path) {
    std::ofstream f(path);
    if (!f) throw IoError(path.string() + ": expected a writable file, found none");
    for (std::size_t v = 0; v < mesh.vertexCount(); ++v)
        f << "v " << mesh.positions[3 * v] << ' ' << mesh.positions[3 * v + 1] << ' '
          << mesh.positions[3 * v + 2] << '\n';
    for (std::size_t t = 0; t < mesh.triangleCount(); ++t)
        f << "f " << mesh.indices[3 * t] + 1 << ' ' << mesh.indices[3 * t + 1] + 1 << ' '
          << mesh.indices[3 * t + 2] + 1 << '\n';
    if (!f) throw IoError(path.string() + ": expected to write the mesh, found a write error");
}

}  // namespace palp::volume
