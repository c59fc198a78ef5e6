// palp's refittable BVH through Embree and on its own: the user geometry under every form of
// ray Embree hands it (single, streams, packets with masks, occlusion), a refit leaving the
// registered box, zero allocations per refit and query, degenerate input, and the tree's depth.
#include <embree3/rtcore.h>
#include <gtest/gtest.h>

#include <Eigen/Core>
#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <random>
#include <vector>

#include "alloc_counter.h"
#include "palp/base/error.h"
#include "palp/kernels/embree_scene.h"
#include "palp/kernels/refit_bvh.h"
#include "refit_bvh_fixtures.h"

namespace {

using namespace palp::kernels;
using namespace palp::kernels::rfix;

// The user geometry under every way Embree hands it rays: single rays, 1M streams (coherent and
// not), packets of 4, 8 and 16 with partial valid masks, occlusion; masks and tnear honoured.
TEST(RefitMesh, EmbreeUserGeometryHandlesStreamsPacketsMasksAndOcclusion) {
    const Shape s = shapes()[0];
    RefitMesh mesh(s.mesh);
    EmbreeScene palp(/*robust=*/true);
    const unsigned geom = palp.addRefitMesh(mesh, kMaskSurface, 0.01f);
    palp.commit();
    ASSERT_EQ(mesh.refit(deformed(s.mesh, s.centre, s.size, 1.0, 2)), RefitStatus::Ok);
    // The twin geometry of the hit id gives the current triangle, as for an Embree mesh.
    const auto* v = static_cast<const float*>(
        rtcGetGeometryBufferData(rtcGetGeometry(palp.handle(), geom), RTC_BUFFER_TYPE_VERTEX, 0));
    ASSERT_EQ(v, mesh.positions().data());

    RandomRays rays(17, s.centre, 3 * s.size, 1.2 * s.size);
    constexpr int kN = 16;
    std::array<Vec3f, kN> org, dir;
    std::array<float, kN> tfar;
    std::array<TriangleHit, kN> want;
    std::array<bool, kN> wantHit;
    RTCIntersectContext ctx;
    int hits = 0;
    for (int round = 0; round < 40; ++round) {
        for (int i = 0; i < kN; ++i) {
            const auto k = static_cast<std::size_t>(i);
            rays.next(org[k], dir[k], tfar[k]);
            wantHit[k] = mesh.intersect(org[k], dir[k], 0.0f, tfar[k], want[k]);
            hits += wantHit[k] ? 1 : 0;
        }
        // 1M stream, both flags.
        for (const auto flag :
             {RTC_INTERSECT_CONTEXT_FLAG_INCOHERENT, RTC_INTERSECT_CONTEXT_FLAG_COHERENT}) {
            std::array<RTCRayHit, kN> rh{};
            for (std::size_t k = 0; k < kN; ++k) {
                rh[k].ray = {org[k][0], org[k][1], org[k][2], 0.0f,     dir[k][0], dir[k][1],
                             dir[k][2], 0.0f,      tfar[k],   kMaskAll, 0,         0};
                rh[k].hit.geomID = RTC_INVALID_GEOMETRY_ID;
            }
            rtcInitIntersectContext(&ctx);
            ctx.flags = flag;
            rtcIntersect1M(palp.handle(), &ctx, rh.data(), kN, sizeof(RTCRayHit));
            for (std::size_t k = 0; k < kN; ++k) {
                ASSERT_EQ(rh[k].hit.geomID != RTC_INVALID_GEOMETRY_ID, wantHit[k]);
                if (!wantHit[k]) continue;
                EXPECT_EQ(rh[k].hit.geomID, geom);
                EXPECT_EQ(rh[k].hit.primID, want[k].primId);
                EXPECT_EQ(rh[k].ray.tfar, want[k].t);
                EXPECT_EQ(rh[k].hit.v, want[k].v);
                EXPECT_EQ(rh[k].hit.Ng_z, want[k].ng[2]);
            }
        }
        // Packets: every other ray valid. Where the CPU has no native packet of a width (16
        // without AVX-512), Embree emulates it through its stream path, which ignores the valid
        // mask (rtcGetDeviceProperty NATIVE_RAY16_SUPPORTED): there the inactive rays are also
        // disabled the other documented way, tnear > tfar, so the test still checks the callback
        // against the rays Embree hands it.
        const RTCDevice device = rtcGetSceneDevice(palp.handle());
        const bool native16 =
            rtcGetDeviceProperty(device, RTC_DEVICE_PROPERTY_NATIVE_RAY16_SUPPORTED) != 0;
        rtcReleaseDevice(device);  // rtcGetSceneDevice retains it
        const auto packet = [&](auto& rh, auto intersect, int width) {
            alignas(64) std::array<int, kN> valid{};  // Embree loads it as a SIMD mask
            for (int i = 0; i < width; ++i) {
                const auto k = static_cast<std::size_t>(i);
                valid[k] = (i + round) % 2 == 0 ? -1 : 0;
                rh.ray.org_x[k] = org[k][0];
                rh.ray.org_y[k] = org[k][1];
                rh.ray.org_z[k] = org[k][2];
                rh.ray.dir_x[k] = dir[k][0];
                rh.ray.dir_y[k] = dir[k][1];
                rh.ray.dir_z[k] = dir[k][2];
                rh.ray.tnear[k] = 0.0f;
                if (width == 16 && !native16 && valid[k] == 0)
                    rh.ray.tnear[k] = std::numeric_limits<float>::infinity();
                rh.ray.tfar[k] = tfar[k];
                rh.ray.time[k] = 0.0f;
                rh.ray.mask[k] = kMaskSurface;
                rh.ray.id[k] = static_cast<unsigned>(i);
                rh.ray.flags[k] = 0;
                rh.hit.geomID[k] = RTC_INVALID_GEOMETRY_ID;
            }
            rtcInitIntersectContext(&ctx);
            intersect(valid.data(), palp.handle(), &ctx, &rh);
            for (int i = 0; i < width; ++i) {
                const auto k = static_cast<std::size_t>(i);
                const bool expect = valid[k] != 0 && wantHit[k];
                ASSERT_EQ(rh.hit.geomID[k] != RTC_INVALID_GEOMETRY_ID, expect)
                    << "width " << width << " lane " << i;
                if (!expect) continue;
                EXPECT_EQ(rh.hit.primID[k], want[k].primId);
                EXPECT_EQ(rh.ray.tfar[k], want[k].t);
                EXPECT_EQ(rh.hit.u[k], want[k].u);
            }
        };
        alignas(16) RTCRayHit4 p4;
        packet(p4, rtcIntersect4, 4);
        alignas(32) RTCRayHit8 p8;
        packet(p8, rtcIntersect8, 8);
        alignas(64) RTCRayHit16 p16;
        packet(p16, rtcIntersect16, 16);
        // Occlusion, a disjoint ray mask, and tnear beyond the hit.
        for (std::size_t k = 0; k < kN; ++k) {
            RTCRay r = {org[k][0], org[k][1], org[k][2], 0.0f,     dir[k][0], dir[k][1],
                        dir[k][2], 0.0f,      tfar[k],   kMaskAll, 0,         0};
            rtcInitIntersectContext(&ctx);
            rtcOccluded1(palp.handle(), &ctx, &r);
            EXPECT_EQ(r.tfar < 0, wantHit[k]);
            RTCRayHit rh;
            EXPECT_FALSE(trace(palp.handle(), org[k], dir[k], 0.0f, tfar[k], kMaskBone, rh));
            if (wantHit[k]) {
                ASSERT_TRUE(trace(palp.handle(), org[k], dir[k], 0.0f, tfar[k], kMaskSurface, rh));
                // Past the first hit, the next one (the far side) or nothing.
                const float t1 = want[k].t;
                if (trace(palp.handle(), org[k], dir[k], t1 * (1 + 1e-4f), tfar[k], kMaskAll, rh)) {
                    EXPECT_GT(rh.ray.tfar, t1);
                }
                EXPECT_FALSE(trace(palp.handle(), org[k], dir[k], 0.0f, 0.999f * t1, kMaskAll, rh));
            }
        }
    }
    // No error on the scene's device (rtcGetSceneDevice retains it).
    RTCDevice device = rtcGetSceneDevice(palp.handle());
    EXPECT_EQ(rtcGetDeviceError(device), RTC_ERROR_NONE);
    rtcReleaseDevice(device);
    EXPECT_GT(hits, 200);
}

// A refit that leaves the box registered with Embree is reported; inside it is not.
TEST(RefitMesh, ReportsLeavingTheRegisteredBox) {
    const Shape s = shapes()[1];
    RefitMesh mesh(s.mesh);
    EmbreeScene palp(true);
    palp.addRefitMesh(mesh, kMaskSurface, 0.005f);
    palp.commit();
    std::vector<float> p = s.mesh.positions;
    for (float& x : p) x += 0.004f;
    EXPECT_EQ(mesh.refit(p), RefitStatus::Ok);
    for (float& x : p) x += 0.002f;
    EXPECT_EQ(mesh.refit(p), RefitStatus::OutsideLimit);
    EXPECT_FLOAT_EQ(mesh.bounds().lo[0], s.mesh.positions[0] + 0.006f);
    EXPECT_THROW(palp.addRefitMesh(mesh, kMaskSurface, -1.0f), palp::ValueError);
    EXPECT_THROW(palp.addRefitMesh(mesh, kMaskSurface, kNan), palp::ValueError);
}

// Refit and queries allocate nothing (directly, through rtcIntersect1, 1M streams and
// rtcOccluded1 on the committed scene).
TEST(RefitMesh, ZeroAllocationsPerRefitAndQuery) {
    const Shape s = shapes()[2];
    RefitMesh mesh(s.mesh);
    EmbreeScene palp(true);
    palp.addRefitMesh(mesh, kMaskSurface, static_cast<float>(s.size));
    palp.commit();
    std::vector<std::vector<float>> frames;
    for (int i = 0; i < 4; ++i) frames.push_back(deformed(s.mesh, s.centre, s.size, 1.0, i));
    RandomRays rays(23, s.centre, 3 * s.size, s.size);
    std::vector<std::array<Vec3f, 2>> rs(256);
    for (auto& r : rs) {
        float tfar;
        rays.next(r[0], r[1], tfar);
    }
    std::array<RTCRayHit, 16> stream{};
    RTCIntersectContext ctx;
    rtcInitIntersectContext(&ctx);
    int hits = 0;
    const std::uint64_t before = palp::test::allocationCount();
    for (int tick = 0; tick < 200; ++tick) {
        if (mesh.refit(frames[static_cast<std::size_t>(tick) % frames.size()]) != RefitStatus::Ok)
            break;
        for (std::size_t i = 0; i < 16; ++i) {
            const auto& r = rs[(16 * static_cast<std::size_t>(tick) + i) % rs.size()];
            TriangleHit h;
            hits += mesh.intersect(r[0], r[1], 0.0f, kInfF, h) ? 1 : 0;
            hits += mesh.occluded(r[0], r[1], 0.0f, kInfF) ? 1 : 0;
            RTCRayHit rh;
            hits += trace(palp.handle(), r[0], r[1], 0.0f, kInfF, kMaskAll, rh) ? 1 : 0;
            RTCRay occ = {r[0][0], r[0][1], r[0][2], 0.0f,     r[1][0], r[1][1],
                          r[1][2], 0.0f,    kInfF,   kMaskAll, 0,       0};
            rtcOccluded1(palp.handle(), &ctx, &occ);
            stream[i].ray = occ;
            stream[i].ray.tfar = kInfF;
            stream[i].hit.geomID = RTC_INVALID_GEOMETRY_ID;
        }
        rtcIntersect1M(palp.handle(), &ctx, stream.data(), 16, sizeof(RTCRayHit));
    }
    EXPECT_EQ(palp::test::allocationCount() - before, 0u);
    EXPECT_GT(hits, 200 * 16);
    // Slack refits (their scratch is reserved by setRefitSlack) allocate nothing either.
    mesh.setRefitSlack(static_cast<float>(0.01 * s.size));
    const std::uint64_t beforeSlack = palp::test::allocationCount();
    for (int tick = 0; tick < 200; ++tick)
        ASSERT_EQ(mesh.refit(frames[static_cast<std::size_t>(tick) % frames.size()]),
                  RefitStatus::Ok);
    EXPECT_EQ(palp::test::allocationCount() - beforeSlack, 0u);
}

// NaN or infinite rays, a zero direction, tnear > tfar and degenerate triangles give no hit
// (and return); bad meshes and bad refits are refused.
TEST(RefitMesh, DegenerateInputGivesNoHit) {
    TriangleMesh m = boxSurface(3, 0.01, Eigen::Vector3d::Zero());
    const auto boxTriangles = static_cast<std::uint32_t>(m.triangleCount());
    // Degenerate triangles inside the box's face plane z = 0 and in the open: a point and a
    // segment.
    const auto base = static_cast<std::uint32_t>(m.vertexCount());
    for (float x : {0.005f, 0.005f, 0.005f, 0.001f, 0.002f, 0.003f})
        m.positions.insert(m.positions.end(), {x, 0.03f, 0.005f});
    m.indices.insert(m.indices.end(), {base, base + 1, base + 2, base + 3, base + 4, base + 5});
    RefitMesh mesh(m);
    const Vec3f o = {0.005f, 0.05f, 0.005f};
    TriangleHit h;
    // Straight at the degenerate triangles: they are skipped, the box top (y = 0.02) is hit.
    ASSERT_TRUE(mesh.intersect(o, {0, -1, 0}, 0.0f, kInfF, h));
    EXPECT_FLOAT_EQ(h.t, 0.03f);
    EXPECT_LT(h.primId, boxTriangles);
    EXPECT_FALSE(mesh.intersect(o, {0, -1, 0}, 0.0f, 0.025f, h));  // only the segment before
    for (const Vec3f& d : std::array<Vec3f, 4>{Vec3f{0, 0, 0}, Vec3f{kNan, -1, 0},
                                               Vec3f{0, -kInfF, 0}, Vec3f{0, -1e-45f, 0}}) {
        // A denormal direction may overflow 1 / d: no hit then, but an answer.
        const bool hit = mesh.intersect(o, d, 0.0f, kInfF, h);
        if (d[1] != -1e-45f) {
            EXPECT_FALSE(hit);
        }
        EXPECT_EQ(mesh.occluded(o, d, 0.0f, kInfF), hit);
    }
    EXPECT_FALSE(mesh.intersect({kNan, 0, 0}, {0, -1, 0}, 0.0f, kInfF, h));
    EXPECT_FALSE(mesh.intersect(o, {0, -1, 0}, kNan, kInfF, h));
    EXPECT_FALSE(mesh.intersect(o, {0, -1, 0}, 0.0f, kNan, h));
    EXPECT_FALSE(mesh.intersect(o, {0, -1, 0}, 1.0f, 0.5f, h));
    // A mesh of degenerate triangles only is never hit.
    TriangleMesh flat;
    flat.positions = {0, 0, 0, 1, 1, 1, 2, 2, 2, 0, 0, 0};
    flat.indices = {0, 1, 2, 0, 3, 0, 1, 1, 1};
    RefitMesh line(flat);
    std::mt19937 rng(1);
    std::uniform_real_distribution<float> u(-1, 1);
    for (int i = 0; i < 1000; ++i) {
        const float s = u(rng) + 1;
        EXPECT_FALSE(line.intersect({s + u(rng), s + u(rng), s - 1}, {0, 0, 1}, 0.0f, kInfF, h));
        EXPECT_FALSE(line.intersect({-1, -1, -1}, {1, 1, 1}, 0.0f, kInfF, h));
    }
    // Refits with a wrong size or a non-finite coordinate change nothing.
    const Box3f before = mesh.bounds();
    std::vector<float> p = m.positions;
    p[4] = kNan;
    EXPECT_EQ(mesh.refit(p), RefitStatus::Rejected);
    p.pop_back();
    EXPECT_EQ(mesh.refit(p), RefitStatus::Rejected);
    EXPECT_EQ(mesh.bounds().lo, before.lo);
    EXPECT_EQ(mesh.bounds().hi, before.hi);
    // Bad meshes.
    TriangleMesh bad = m;
    bad.indices[7] = 1000;
    EXPECT_THROW(RefitMesh{bad}, palp::ValueError);
    bad = m;
    bad.positions[2] = kInfF;
    EXPECT_THROW(RefitMesh{bad}, palp::ValueError);
    EXPECT_THROW(RefitMesh{TriangleMesh{}}, palp::ValueError);
    EXPECT_THROW(RefitMesh(m, 0), palp::ValueError);
}

// The tree's depth stays near log2(#T / leafSize) (binned SAH, median splits when the centroids
// coincide), within the fixed traversal stack; every triangle is reachable.
TEST(RefitMesh, TreeDepthIsBounded) {
    for (const Shape& s : shapes()) {
        for (int leaf : {1, 4, 16}) {
            RefitMesh mesh(s.mesh, leaf);
            const double log2n = std::log2(static_cast<double>(s.mesh.triangleCount()) / leaf);
            EXPECT_LE(mesh.depth(), static_cast<int>(2 * std::ceil(log2n)) + 1)
                << s.name << " leaf " << leaf;
            EXPECT_LE(mesh.nodeCount(), 2 * s.mesh.triangleCount());
        }
    }
    // 1,000 copies of one triangle: no centroid spread, so median splits: a balanced tree; a ray
    // through it hits one of them (all tie).
    TriangleMesh same;
    same.positions = {0, 0, 0, 1, 0, 0, 0, 1, 0};
    for (int i = 0; i < 1000; ++i) same.indices.insert(same.indices.end(), {0, 1, 2});
    RefitMesh mesh(same, 2);
    EXPECT_LE(mesh.depth(), 10);
    TriangleHit h;
    ASSERT_TRUE(mesh.intersect({0.25f, 0.25f, 1}, {0, 0, -1}, 0.0f, kInfF, h));
    EXPECT_EQ(h.t, 1.0f);
    EXPECT_LT(h.primId, 1000u);
}

}  // namespace
