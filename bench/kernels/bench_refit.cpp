// Deforming-surface benchmark: palp's refit BVH (refit_bvh.h) against Embree's deforming
// triangle mesh, on the boundary of a hex grid (2k and 32k triangles) under a moving dent.
//  * per update: RefitMesh::refit (copy + refit) vs EmbreeScene::updateVertices + commit (REFIT
//    quality), interleaved frame by frame in one run;
//  * closest hit of a 17-ray bundle (kernels::traceBundle, default mode) against the palp user
//    geometry vs Embree's triangle mesh (both robust scenes), interleaved; and the same 17 rays
//    through RefitMesh::intersect directly (no Embree around it).
// Each line: both figures (median microseconds) and the ratio Embree / palp.
// Usage: bench_refit [frames]   (default 2000)
#include <embree3/rtcore.h>

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <exception>
#include <functional>
#include <vector>

#include "palp/kernels/embree_scene.h"
#include "palp/kernels/ray_bundle.h"
#include "palp/kernels/refit_bvh.h"

namespace {

using namespace palp::kernels;
using Clock = std::chrono::steady_clock;

/// Boundary of an n^3 hex grid of spacing h from the origin: 12 (n - 1)^2 triangles.
TriangleMesh gridSurface(int n, float h) {
    TriangleMesh m;
    std::vector<std::int64_t> id(
        static_cast<std::size_t>(n) * static_cast<std::size_t>(n) * static_cast<std::size_t>(n),
        -1);
    const auto vertex = [&](int i, int j, int k) {
        std::int64_t& v = id[static_cast<std::size_t>((k * n + j) * n + i)];
        if (v < 0) {
            v = static_cast<std::int64_t>(m.vertexCount());
            m.positions.insert(
                m.positions.end(),
                {h * static_cast<float>(i), h * static_cast<float>(j), h * static_cast<float>(k)});
        }
        return static_cast<std::uint32_t>(v);
    };
    for (int a = 0; a < 3; ++a)
        for (int side = 0; side < 2; ++side)
            for (int p = 0; p + 1 < n; ++p)
                for (int q = 0; q + 1 < n; ++q) {
                    std::array<std::uint32_t, 4> c{};
                    const int pq[4][2] = {{p, q}, {p + 1, q}, {p + 1, q + 1}, {p, q + 1}};
                    for (std::size_t k = 0; k < 4; ++k) {
                        std::array<int, 3> ijk{};
                        ijk[static_cast<std::size_t>(a)] = side == 0 ? 0 : n - 1;
                        ijk[static_cast<std::size_t>((a + 1) % 3)] = pq[k][0];
                        ijk[static_cast<std::size_t>((a + 2) % 3)] = pq[k][1];
                        c[k] = vertex(ijk[0], ijk[1], ijk[2]);
                    }
                    if (side == 1)
                        m.indices.insert(m.indices.end(), {c[0], c[1], c[2], c[0], c[2], c[3]});
                    else
                        m.indices.insert(m.indices.end(), {c[0], c[2], c[1], c[0], c[3], c[2]});
                }
    return m;
}

/// Rest positions with a Gaussian dent (depth 10 % of the size) under a point circling the
/// y = 0 face, frame @p f.
void dent(const TriangleMesh& m, float size, int f, std::vector<float>& out) {
    const float cx = size * (0.5f + 0.25f * std::cos(0.01f * static_cast<float>(f)));
    const float cz = size * (0.5f + 0.25f * std::sin(0.01f * static_cast<float>(f)));
    const float s2 = 2 * (0.15f * size) * (0.15f * size);
    for (std::size_t v = 0; v < m.vertexCount(); ++v) {
        const float x = m.positions[3 * v], y = m.positions[3 * v + 1], z = m.positions[3 * v + 2];
        const float r2 = (x - cx) * (x - cx) + (z - cz) * (z - cz);
        out[3 * v] = x;
        out[3 * v + 1] = y + 0.1f * size * std::exp(-r2 / s2) * (1 - y / size);
        out[3 * v + 2] = z;
    }
}

double median(std::vector<double> v) {
    std::nth_element(v.begin(), v.begin() + static_cast<std::ptrdiff_t>(v.size() / 2), v.end());
    return v[v.size() / 2];
}

template <class F>
double timeUs(F&& f) {
    const auto t0 = Clock::now();
    f();
    return std::chrono::duration<double, std::micro>(Clock::now() - t0).count();
}

void line(const char* what, const char* a, double ta, const char* b, double tb) {
    std::printf("%-34s %s %9.2f us   %s %9.2f us   ratio %6.1fx\n", what, a, ta, b, tb, tb / ta);
}

void run(int n, int frames) {
    const float size = 0.04f;
    const TriangleMesh mesh = gridSurface(n, size / static_cast<float>(n - 1));
    RefitMesh refit(mesh);
    EmbreeScene palp(/*robust=*/true);
    palp.addRefitMesh(refit, kMaskSurface, size);
    palp.commit();
    EmbreeScene embree(/*robust=*/true);
    const unsigned geom = embree.addDeformingMesh(mesh, kMaskSurface);
    embree.commit();

    std::vector<float> p(mesh.positions.size());
    std::vector<double> tRefit, tCommit, tPalpBundle, tEmbreeBundle, tDirect, tPalpLoop,
        tEmbreeLoop;
    BundleParams bp;
    bp.length = 0.02;
    RayBundle bundle;
    BundleHits hits;
    int hitCount = 0, refitOutside = 0;
    for (int f = 0; f < frames; ++f) {
        dent(mesh, size, f, p);
        // Interleaved, alternating which goes first.
        const auto doRefit = [&] {
            tRefit.push_back(timeUs([&] {
                if (refit.refit(p) != RefitStatus::Ok) ++refitOutside;
            }));
        };
        const auto doCommit = [&] {
            tCommit.push_back(timeUs([&] {
                embree.updateVertices(geom, p);
                embree.commit();
            }));
        };
        if (f % 2 == 0) {
            doRefit();
            doCommit();
        } else {
            doCommit();
            doRefit();
        }
        // A bundle from above the dented face, pressing in along +y.
        const double ang = 0.013 * f;
        const Eigen::Vector3d origin(size * (0.5 + 0.3 * std::cos(ang)), -0.005,
                                     size * (0.5 + 0.3 * std::sin(ang)));
        generateBundle(origin, Eigen::Vector3d(0.1 * std::sin(ang), 1, 0.05),
                       Eigen::Vector3d::UnitX(), Eigen::Vector3d::UnitZ(), bp, bundle);
        // Five queries of the same bundle, in an order rotated frame by frame so that each
        // follows each of the others (and their cache footprint) equally often.
        const std::array<std::function<void()>, 5> queries = {
            [&] {
                tPalpBundle.push_back(
                    timeUs([&] { traceBundle(palp, bundle, kMaskSurface, hits); }));
                for (int r = 0; r < hits.count; ++r)
                    hitCount += hits.hit[static_cast<std::size_t>(r)];
            },
            [&] {
                tEmbreeBundle.push_back(
                    timeUs([&] { traceBundle(embree, bundle, kMaskSurface, hits); }));
            },
            [&] {
                tPalpLoop.push_back(timeUs(
                    [&] { traceBundle(palp, bundle, kMaskSurface, hits, MeshTraceMode::Loop1); }));
            },
            [&] {
                tEmbreeLoop.push_back(timeUs([&] {
                    traceBundle(embree, bundle, kMaskSurface, hits, MeshTraceMode::Loop1);
                }));
            },
            [&] {
                tDirect.push_back(timeUs([&] {
                    TriangleHit h;
                    for (int r = 0; r < bundle.count; ++r) {
                        const auto i = static_cast<std::size_t>(r);
                        hitCount += refit.intersect({bundle.ox[i], bundle.oy[i], bundle.oz[i]},
                                                    {bundle.dx[i], bundle.dy[i], bundle.dz[i]},
                                                    0.0f, bundle.length[i], h)
                                        ? 1
                                        : 0;
                    }
                }));
            }};
        for (std::size_t q = 0; q < queries.size(); ++q)
            queries[(q + static_cast<std::size_t>(f) * 2) % queries.size()]();
    }
    std::printf(
        "grid surface %d^3 nodes: %zu triangles, palp BVH %zu nodes, depth %d; %d frames "
        "(%d bundle hits, %d refits outside the box)\n",
        n, mesh.triangleCount(), refit.nodeCount(), refit.depth(), frames, hitCount, refitOutside);
    line("update (refit) per frame", "palp", median(tRefit), "embree", median(tCommit));
    line("17-ray bundle closest hit", "palp", median(tPalpBundle), "embree", median(tEmbreeBundle));
    line("17-ray bundle, rtcIntersect1 each", "palp", median(tPalpLoop), "embree",
         median(tEmbreeLoop));
    line("17 rays, RefitMesh::intersect", "palp", median(tDirect), "embree", median(tEmbreeBundle));
}

}  // namespace

int main(int argc, char** argv) {
    try {
        const int frames = argc > 1 ? std::max(10, std::atoi(argv[1])) : 2000;
        std::printf("median over frames; ratio = embree / palp (> 1: palp faster)\n");
        run(14, frames);  // 2,028 triangles (a 14^3-node hex surface)
        run(53, frames);  // 32,448 triangles
        return 0;
    } catch (const std::exception& e) {
        std::fprintf(stderr, "bench_refit: error: %s\n", e.what());
        return 1;
    }
}
