// A patient's CT deformable on the threaded regions, as palp palpate runs it (issue 32): the
// shared head CT (ct-ge-head-tilt, 1 mm voxels, 5 mm cells, bone fixed, the regions under the
// press and sliding over the skin facing it). A session presses the back of the head and holds;
// the servo's ticks allocate nothing (the secondary stalled while counting: its solver
// allocates), the skin pushes the hand back and is dented, and no tick is flagged.
#include <gtest/gtest.h>
#include <tbb/global_control.h>

#include <chrono>
#include <cstdint>
#include <cstdio>
#include <thread>

#include "alloc_counter.h"
#include "deformable_fixtures.h"
#include "palp/fem/async_regions.h"
#include "palp/haptics/session.h"
#include "palp/haptics/tissue/deformable.h"
#include "palp/haptics/tissue/deformable_setup.h"
#include "palp/volume/load.h"
#include "session_fixtures.h"
#include "test_support.h"

namespace palp::haptics {
namespace {

using namespace dfix;

TEST(DeformableHead, TheHeadCtOnThreadedRegionsTicksWithoutAllocating) {
    const auto dir = test::dataPath("ct-ge-head-tilt");
    if (dir.empty()) GTEST_SKIP() << "no shared data";
    volume::LoadOptions lo;
    lo.resample.voxelSize = 1e-3;
    // The scan is read on one thread: what this test checks under ThreadSanitizer
    // (tools/test_threads.sh) is the servo against the regions' secondary and layout threads.
    // The loader's parallel decode of this series has a report of its own under TSan (a write
    // on the calling thread whose stack TSan lost, read in LazyWindow::decode's parallel loop),
    // not yet explained; the volume tests own it.
    const volume::Volume head = [&] {
        tbb::global_control one(tbb::global_control::max_allowed_parallelism, 1);
        return volume::load({dir}, lo);
    }();
    DeformableSetup setup;  // palp palpate's tissue: 5 mm cells, bone above 500 HU fixed
    setup.options.solverKind = DeformableSolver::asyncRegions;
    setup.options.regions.threaded = true;
    setup.options.regions.lod = 0;
    setup.options.regionsCentre = mm(1, 96, 20);  // the skin where the hand presses
    // The skin facing a press along -y around it: what the contact slides over.
    setup.slidePatch = SlidePatch{mm(1, 100, 20),
                                  Eigen::Vector3d::UnitX(),
                                  Eigen::Vector3d::UnitZ(),
                                  -Eigen::Vector3d::UnitY(),
                                  40e-3,
                                  40e-3};
    const auto model = makeDeformableModel(head, setup);
    ASSERT_EQ(model->options().solverKind, DeformableSolver::asyncRegions);
    EXPECT_GT(model->options().regions.slideNodes.size(), 20u);
    auto scene = deformableScene(model);
    // From 9 mm behind the skin to 6 mm into it in 0.3 s, then held.
    PathDevice device({{0.0, mm(1, 105, 20)}, {0.3, mm(1, 90, 20)}, {1.2, mm(1, 90, 20)}});
    Session session(scene, device, vcParams(300));
    fem::AsyncRegions* regions = const_cast<DeformableBody*>(session.deformable())->regions();
    ASSERT_NE(regions, nullptr);
    // Until the press is held, at about real-time pace so the secondary keeps up.
    for (int i = 0; i < 400; ++i) {
        session.step();
        std::this_thread::sleep_for(std::chrono::microseconds(500));
    }
    EXPECT_GT(regions->secondaryStats().used, 0u);
    regions->setSecondaryStalledForTest(true);
    std::this_thread::sleep_for(std::chrono::milliseconds(50));
    const std::uint64_t before = test::threadAllocationCount();
    int contact = 0, stale = 0;
    Snapshot last;
    for (int i = 400; i < 1200; ++i) {
        const Snapshot& s = session.step();
        contact += s.contactCount > 0 ? 1 : 0;
        // The stall is flagged to the host after 0.5 s of ticks without a solution; nothing else.
        stale += (s.femFlags & fem::kAsyncSecondaryStale) ? 1 : 0;
        if (!s.force.allFinite() || (s.femFlags & ~fem::kAsyncSecondaryStale) != 0 || s.faulted) {
            ADD_FAILURE() << "tick " << i << " flags " << s.femFlags;
            break;
        }
        last = s;
    }
    EXPECT_EQ(test::threadAllocationCount() - before, 0u);
    EXPECT_GT(stale, 0);
    regions->setSecondaryStalledForTest(false);
    std::printf(
        "head CT: %zu slide nodes, lod %d, contact %d of 800 ticks, force y %.3f N, "
        "dent %.2f mm, %llu secondary solutions used\n",
        model->options().regions.slideNodes.size(), model->options().regions.lod, contact,
        last.force.y(), last.maxDisplacement * 1e3,
        static_cast<unsigned long long>(regions->secondaryStats().used));
    EXPECT_GT(contact, 700);
    EXPECT_GT(last.force.y(), 0.02);        // the skin pushes the hand back (+y)
    EXPECT_GT(last.maxDisplacement, 1e-4);  // and is dented
}

}  // namespace
}  // namespace palp::haptics
