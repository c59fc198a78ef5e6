// The tumour phantom: a soft block with a stiffer spherical inclusion, its analytic values, its
// inclusion geometry and the inclusion's surface mesh (closed, outward, on the sphere).
#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <cmath>
#include <limits>
#include <map>
#include <numbers>
#include <utility>

#include "palp/base/error.h"
#include "palp/volume/phantom.h"
#include "test_support.h"

namespace {

using namespace palp::volume;
using Eigen::Vector3d;
using palp::test::expectThrowWith;

constexpr double kMm = 1e-3;

Vector3d mm(double x, double y, double z) { return Vector3d(x, y, z) * kMm; }

PhantomParams tumour() {
    PhantomParams p;
    p.scene = PhantomScene::Tumour;
    return p;
}

Vector3d vertex(const palp::TriangleMesh& m, std::uint32_t v) {
    return {m.positions[3 * v], m.positions[3 * v + 1], m.positions[3 * v + 2]};
}

TEST(PhantomTumour, ValuesInsideAndOutsideTheInclusion) {
    const Phantom ph(tumour());
    const PhantomSphere s = ph.inclusion();
    EXPECT_EQ(s.centre, mm(0, 16, 0));
    EXPECT_EQ(s.radius, 8 * kMm);
    EXPECT_EQ(ph.valueAt(s.centre), 200);
    // Just inside and just outside the sphere along several directions.
    for (const Vector3d& d : {Vector3d(1, 0, 0), Vector3d(0, -1, 0), Vector3d(0, 1, 0),
                              Vector3d(1, 1, 1).normalized(), Vector3d(-2, 1, 3).normalized()}) {
        EXPECT_EQ(ph.valueAt(s.centre + 0.99 * s.radius * d), 200) << d.transpose();
        EXPECT_EQ(ph.valueAt(s.centre + 1.01 * s.radius * d), 40) << d.transpose();
    }
    EXPECT_EQ(ph.valueAt(mm(0, 1, 0)), -100);     // fat layer
    EXPECT_EQ(ph.valueAt(mm(0, 40, 0)), 40);      // soft tissue below the inclusion
    EXPECT_EQ(ph.valueAt(mm(0, -1, 0)), -1000);   // air above the surface
    EXPECT_EQ(ph.valueAt(mm(60, 16, 0)), -1000);  // beside the block
    const WorldBox b = ph.bounds();
    EXPECT_EQ(b.min, mm(-50, 0, -50));
    EXPECT_EQ(b.max, mm(50, 50, 50));
    EXPECT_EQ(ph.description(), "tumour centre=(0,16,0)mm radius=8mm fat=2mm");

    // Moved and resized, with its own material value.
    PhantomParams p = tumour();
    p.inclusionCentre = mm(20, 25, -15);
    p.inclusionRadius = 6 * kMm;
    p.materials.inclusionHu = 250;
    const Phantom moved(p);
    EXPECT_EQ(moved.valueAt(mm(20, 25, -15)), 250);
    EXPECT_EQ(moved.valueAt(mm(20, 25, -8.9)), 40);
    EXPECT_EQ(moved.valueAt(mm(0, 16, 0)), 40);
    EXPECT_EQ(moved.inclusion().centre, mm(20, 25, -15));
}

TEST(PhantomTumour, InclusionMeshIsAClosedOutwardSphere) {
    const Phantom ph(tumour());
    const PhantomSphere s = ph.inclusion();
    const palp::TriangleMesh m = ph.inclusionMesh();
    EXPECT_EQ(m.triangleCount(), 1280u);
    EXPECT_EQ(m.vertexCount(), 642u);
    // Closed and consistently oriented: every directed edge once, its reverse once.
    std::map<std::pair<std::uint32_t, std::uint32_t>, int> directed;
    for (std::size_t t = 0; t < m.triangleCount(); ++t) {
        for (int k = 0; k < 3; ++k) {
            const std::uint32_t a = m.indices[3 * t + static_cast<std::size_t>(k)];
            const std::uint32_t b = m.indices[3 * t + static_cast<std::size_t>((k + 1) % 3)];
            ASSERT_NE(a, b);
            ++directed[{a, b}];
        }
    }
    for (const auto& [edge, count] : directed) {
        EXPECT_EQ(count, 1) << edge.first << "-" << edge.second;
        EXPECT_EQ(directed.count({edge.second, edge.first}), 1u)
            << "edge " << edge.first << "-" << edge.second << " has one triangle";
    }
    EXPECT_EQ(directed.size(), 3u * 1280u);  // 1920 edges, each in both directions
    // Every vertex on the sphere (float positions).
    for (std::uint32_t v = 0; v < m.vertexCount(); ++v) {
        EXPECT_NEAR((vertex(m, v) - s.centre).norm(), s.radius, 1e-6 * s.radius) << v;
    }
    // Outward: signed volume positive, close to the sphere's; each normal points away.
    double volume = 0;
    for (std::size_t t = 0; t < m.triangleCount(); ++t) {
        const Vector3d a = vertex(m, m.indices[3 * t]) - s.centre;
        const Vector3d b = vertex(m, m.indices[3 * t + 1]) - s.centre;
        const Vector3d c = vertex(m, m.indices[3 * t + 2]) - s.centre;
        volume += a.dot(b.cross(c)) / 6.0;
        EXPECT_GT((b - a).cross(c - a).dot(a + b + c), 0.0) << "triangle " << t;
    }
    const double sphere = 4.0 / 3.0 * std::numbers::pi * std::pow(s.radius, 3);
    EXPECT_GT(volume, 0.98 * sphere);
    EXPECT_LT(volume, sphere);  // inscribed
}

TEST(PhantomTumour, IcosphereCountsPerSubdivision) {
    for (int sub = 0; sub <= 4; ++sub) {
        const palp::TriangleMesh m = icosphere({mm(1, 2, 3), 0.01}, sub);
        const std::size_t f = 20u << (2 * sub);
        EXPECT_EQ(m.triangleCount(), f);
        EXPECT_EQ(m.vertexCount(), f / 2 + 2);  // Euler: V - E + F = 2 with E = 3F/2
    }
}

TEST(PhantomTumour, NamesAndRefusals) {
    EXPECT_EQ(parseScene("tumour"), PhantomScene::Tumour);
    EXPECT_STREQ(sceneName(PhantomScene::Tumour), "tumour");
    expectThrowWith<palp::ValueError>([] { parseScene("tumor"); },
                                      {"avc, avcec, bone, stiffness or tumour", "'tumor'"});
    PhantomParams avc;
    expectThrowWith<palp::ValueError>([&] { Phantom(avc).inclusion(); },
                                      {"phantom inclusion", "tumour scene", "found avc"});
    expectThrowWith<palp::ValueError>([&] { Phantom(avc).inclusionMesh(); }, {"tumour scene"});
    PhantomParams p = tumour();
    p.inclusionRadius = 30 * kMm;
    expectThrowWith<palp::ValueError>([&] { const Phantom ph(p); },
                                      {"phantom inclusion radius", "[0.5mm, 20mm]", "30mm"});
    p = tumour();
    p.inclusionCentre = mm(0, 9, 0);  // pokes into the 2 mm fat layer
    expectThrowWith<palp::ValueError>([&] { const Phantom ph(p); },
                                      {"phantom inclusion", "inside the block below the fat layer",
                                       "(0, 9, 0) mm", "radius 8mm"});
    p.inclusionCentre = mm(45, 16, 0);  // through the side x = 50 mm
    expectThrowWith<palp::ValueError>([&] { const Phantom ph(p); }, {"(45, 16, 0) mm"});
    p.inclusionCentre.y() = std::numeric_limits<double>::quiet_NaN();
    expectThrowWith<palp::ValueError>([&] { const Phantom ph(p); },
                                      {"phantom inclusion centre y", "nan"});
    p = tumour();
    p.materials.inclusionHu = std::numeric_limits<double>::infinity();
    expectThrowWith<palp::ValueError>([&] { const Phantom ph(p); }, {"inclusion HU", "inf"});
    expectThrowWith<palp::ValueError>(
        [] {
            icosphere({Vector3d::Zero(), 0.01}, 7);
        },
        {"icosphere subdivisions", "0 to 6", "7"});
    expectThrowWith<palp::ValueError>(
        [] {
            icosphere({Vector3d::Zero(), 0.0}, 2);
        },
        {"icosphere radius"});
}

TEST(PhantomTumour, VolumeShowsTheInclusion) {
    PhantomSpec spec;
    spec.params = tumour();
    spec.voxelSize = 1e-3;
    spec.margin = 0;
    const Volume vol = makePhantomVolume(spec);
    // Voxels above halfway between soft tissue and the inclusion: the sphere's volume.
    std::size_t inside = 0;
    for (auto it = vol.grid->cbeginValueOn(); it; ++it) {
        if (*it > 120.0f) ++inside;
    }
    const double sphere = 4.0 / 3.0 * std::numbers::pi * 8 * 8 * 8;  // mm^3 = voxels
    EXPECT_NEAR(static_cast<double>(inside), sphere, 0.03 * sphere);
    EXPECT_NE(vol.info.sourceDescription.find("tumour centre=(0,16,0)mm radius=8mm"),
              std::string::npos)
        << vol.info.sourceDescription;
}

}  // namespace
