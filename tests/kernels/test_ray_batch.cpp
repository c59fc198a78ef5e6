// The ray batch API (TBB workers over many bundles) against the single-thread path, for volumes
// and meshes. Its own executable so that the ThreadSanitizer run (tools/test_threads.sh) builds
// only this threaded case, not the ray accuracy tests and the benchmark harness.
#include <gtest/gtest.h>
#include <tbb/task_arena.h>

#include <random>
#include <vector>

#include "mesh_test_shapes.h"
#include "palp/base/error.h"
#include "palp/kernels/embree_scene.h"
#include "palp/kernels/hit_field.h"
#include "palp/kernels/ray_batch.h"
#include "palp/kernels/volume_ray.h"
#include "palp/kernels/volume_view.h"
#include "ray_test_shapes.h"

namespace {

using namespace palp::kernels;
using palp::test::bundleAt;
using palp::test::icosphere;

// The batch API equals the single-thread path, for volumes and meshes (run under tsan).
TEST(RayBatch, ParallelEqualsSingleThread) {
    const palp::test::Sphere s{Eigen::Vector3d(0, 0, 0), 6e-3};
    auto grid = palp::test::shapeVolume([&](const Eigen::Vector3d& x) { return s.sdf(x); },
                                        {-20, -20, -20}, {20, 20, 20});
    const VolumeView view(grid);
    EmbreeScene scene;
    scene.addRigidMesh(icosphere(s, 3));
    scene.commit();
    std::mt19937 rng(17);
    std::normal_distribution<double> n;
    std::vector<RayBundle> bundles(400);
    for (auto& b : bundles)
        b = bundleAt(9e-3 * Eigen::Vector3d(n(rng), n(rng), n(rng)).normalized(),
                     3e-3 * Eigen::Vector3d(n(rng), n(rng), n(rng)).normalized(), 8);
    FirstHitParams fp;
    fp.threshold = palp::test::kIso;
    AccumulateParams ap;
    ap.sigma = TransferFunction::step(200.0f, 3000.0f);
    std::vector<BundleHits> v1(bundles.size()), vN(bundles.size()), m1(bundles.size()),
        mN(bundles.size());
    std::vector<BundleAccumulation> a1(bundles.size()), aN(bundles.size());
    // The same first-hit through a HitField shared by the workers (immutable).
    const HitField field(view, fp.threshold);
    FirstHitParams withField = fp;
    withField.field = &field;
    std::vector<BundleHits> f1(bundles.size()), fN(bundles.size());
    for (std::size_t i = 0; i < bundles.size(); ++i) {
        traceFirstHit(view, bundles[i], fp, v1[i]);
        traceFirstHit(view, bundles[i], withField, f1[i]);
        traceAccumulate(view, bundles[i], ap, a1[i]);
        traceBundle(scene, bundles[i], kMaskAll, m1[i]);
    }
    tbb::task_arena arena(2);
    arena.execute([&] {
        traceFirstHitBatch(view, bundles, fp, vN);
        traceFirstHitBatch(view, bundles, withField, fN);
        traceAccumulateBatch(view, bundles, ap, aN);
        traceMeshBatch(scene, bundles, kMaskAll, mN);
    });
    int hits = 0;
    for (std::size_t i = 0; i < bundles.size(); ++i) {
        ASSERT_EQ(vN[i].count, 25);
        for (std::size_t r = 0; r < 25; ++r) {
            EXPECT_EQ(v1[i].t[r], vN[i].t[r]);
            EXPECT_EQ(v1[i].hit[r], vN[i].hit[r]);
            EXPECT_EQ(f1[i].t[r], fN[i].t[r]);
            EXPECT_EQ(f1[i].hit[r], fN[i].hit[r]);
            // The field's own lattice: the same hits, t within float rounding.
            EXPECT_EQ(v1[i].hit[r], f1[i].hit[r]);
            EXPECT_NEAR(v1[i].t[r], f1[i].t[r], 1e-3 * view.voxelSize());
            EXPECT_EQ(a1[i].t[r], aN[i].t[r]);
            EXPECT_EQ(a1[i].integral[r], aN[i].integral[r]);
            EXPECT_EQ(m1[i].t[r], mN[i].t[r]);
            EXPECT_EQ(m1[i].hit[r], mN[i].hit[r]);
            hits += vN[i].hit[r];
        }
    }
    EXPECT_GT(hits, 1000);
    std::vector<BundleHits> small(3);
    EXPECT_THROW(traceFirstHitBatch(view, bundles, fp, small), palp::ValueError);
}

}  // namespace
