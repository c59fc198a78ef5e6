#pragma once
// Shared by the refittable-BVH tests (test_refit_bvh*.cpp): closed test meshes (UV sphere, box
// surfaces), a smooth deformation, random rays around a shape, raw Embree closest-hit queries
// and the three shapes every test runs on.
#include <embree3/rtcore.h>

#include <Eigen/Core>
#include <array>
#include <cmath>
#include <cstdint>
#include <limits>
#include <random>
#include <vector>

#include "palp/kernels/embree_scene.h"
#include "palp/kernels/refit_bvh.h"

namespace palp::kernels::rfix {

using Vec3f = std::array<float, 3>;

inline constexpr float kNan = std::numeric_limits<float>::quiet_NaN();
inline constexpr float kInfF = std::numeric_limits<float>::infinity();

/// Closed UV sphere (shared vertices, poles single vertices), outward winding.
inline TriangleMesh sphereMesh(const Eigen::Vector3d& c, double r, int rings, int segments) {
    TriangleMesh m;
    const auto add = [&](const Eigen::Vector3d& p) {
        for (int a = 0; a < 3; ++a) m.positions.push_back(static_cast<float>(p[a]));
    };
    add(c + Eigen::Vector3d(0, 0, r));
    for (int i = 1; i < rings; ++i) {
        const double th = M_PI * i / rings;
        for (int j = 0; j < segments; ++j) {
            const double ph = 2 * M_PI * j / segments;
            add(c + r * Eigen::Vector3d(std::sin(th) * std::cos(ph), std::sin(th) * std::sin(ph),
                                        std::cos(th)));
        }
    }
    add(c + Eigen::Vector3d(0, 0, -r));
    const auto ring = [&](int i, int j) {
        return static_cast<std::uint32_t>(1 + (i - 1) * segments + (j % segments));
    };
    const auto south = static_cast<std::uint32_t>(1 + (rings - 1) * segments);
    for (int j = 0; j < segments; ++j) {
        m.indices.insert(m.indices.end(), {0u, ring(1, j), ring(1, j + 1)});
        for (int i = 1; i + 1 < rings; ++i) {
            m.indices.insert(m.indices.end(), {ring(i, j), ring(i + 1, j), ring(i + 1, j + 1)});
            m.indices.insert(m.indices.end(), {ring(i, j), ring(i + 1, j + 1), ring(i, j + 1)});
        }
        m.indices.insert(m.indices.end(), {ring(rings - 1, j), south, ring(rings - 1, j + 1)});
    }
    return m;
}

/// Closed surface of a box of @p n nodes per axis (the boundary of an n^3 hex grid), spacing
/// @p h, from @p lo: 12 (n - 1)^2 triangles with shared vertices, outward winding.
inline TriangleMesh boxSurface(int n, double h, const Eigen::Vector3d& lo) {
    TriangleMesh m;
    std::vector<std::int64_t> id(static_cast<std::size_t>(n * n * n), -1);
    const auto vertex = [&](int i, int j, int k) {
        std::int64_t& v = id[static_cast<std::size_t>((k * n + j) * n + i)];
        if (v < 0) {
            v = static_cast<std::int64_t>(m.vertexCount());
            const Eigen::Vector3d p = lo + h * Eigen::Vector3d(i, j, k);
            for (int a = 0; a < 3; ++a) m.positions.push_back(static_cast<float>(p[a]));
        }
        return static_cast<std::uint32_t>(v);
    };
    // Each face: axis a fixed at 0 or n-1, (b, c) the other two axes in right-handed order.
    for (int a = 0; a < 3; ++a) {
        const int b = (a + 1) % 3, c = (a + 2) % 3;
        for (int side = 0; side < 2; ++side) {
            for (int p = 0; p + 1 < n; ++p)
                for (int q = 0; q + 1 < n; ++q) {
                    std::array<std::uint32_t, 4> quad;
                    const std::array<std::array<int, 2>, 4> corners = {
                        std::array<int, 2>{p, q}, {p + 1, q}, {p + 1, q + 1}, {p, q + 1}};
                    for (std::size_t k = 0; k < 4; ++k) {
                        std::array<int, 3> ijk{};
                        ijk[static_cast<std::size_t>(a)] = side == 0 ? 0 : n - 1;
                        ijk[static_cast<std::size_t>(b)] = corners[k][0];
                        ijk[static_cast<std::size_t>(c)] = corners[k][1];
                        quad[k] = vertex(ijk[0], ijk[1], ijk[2]);
                    }
                    // b x c = a: counter-clockwise in (b, c) faces +a; flip on the low side.
                    if (side == 1) {
                        m.indices.insert(m.indices.end(), {quad[0], quad[1], quad[2]});
                        m.indices.insert(m.indices.end(), {quad[0], quad[2], quad[3]});
                    } else {
                        m.indices.insert(m.indices.end(), {quad[0], quad[2], quad[1]});
                        m.indices.insert(m.indices.end(), {quad[0], quad[3], quad[2]});
                    }
                }
        }
    }
    return m;
}

/// A smooth deformation of step @p s: a dent along +y under the centre, a twist about y and a
/// squash, scaled by @p amount (1: about a fifth of the size).
inline std::vector<float> deformed(const TriangleMesh& m, const Eigen::Vector3d& centre,
                                   double size, double amount, int s) {
    std::vector<float> out(m.positions.size());
    const double phase = 0.7 * s;
    for (std::size_t v = 0; v < m.vertexCount(); ++v) {
        Eigen::Vector3d p(m.positions[3 * v], m.positions[3 * v + 1], m.positions[3 * v + 2]);
        Eigen::Vector3d q = (p - centre) / size;
        const double dent = 0.2 * amount * std::exp(-4 * (q.x() * q.x() + q.z() * q.z()));
        const double twist = 0.3 * amount * std::sin(phase) * q.y();
        const double c = std::cos(twist), sn = std::sin(twist);
        q = Eigen::Vector3d(c * q.x() - sn * q.z(), q.y() * (1 - 0.1 * amount * std::cos(phase)),
                            sn * q.x() + c * q.z());
        q.y() += dent * (q.y() < 0 ? 1 : 0.3);
        p = centre + size * q;
        for (int a = 0; a < 3; ++a)
            out[3 * v + static_cast<std::size_t>(a)] = static_cast<float>(p[a]);
    }
    return out;
}

/// Closest hit through raw Embree (every field of @p rh, as the reference scene reports it).
inline bool trace(RTCScene s, const Vec3f& o, const Vec3f& d, float tnear, float tfar,
                  unsigned mask, RTCRayHit& rh) {
    RTCIntersectContext ctx;
    rtcInitIntersectContext(&ctx);
    rh.ray.org_x = o[0];
    rh.ray.org_y = o[1];
    rh.ray.org_z = o[2];
    rh.ray.dir_x = d[0];
    rh.ray.dir_y = d[1];
    rh.ray.dir_z = d[2];
    rh.ray.tnear = tnear;
    rh.ray.tfar = tfar;
    rh.ray.time = 0.0f;
    rh.ray.mask = mask;
    rh.ray.id = 0;
    rh.ray.flags = 0;
    rh.hit.geomID = RTC_INVALID_GEOMETRY_ID;
    rh.hit.instID[0] = RTC_INVALID_GEOMETRY_ID;
    rtcIntersect1(s, &ctx, &rh);
    return rh.hit.geomID != RTC_INVALID_GEOMETRY_ID;
}

/// Random rays from a shell around @p centre toward random points in a ball of radius
/// @p aim, some of them too short to reach the surface.
struct RandomRays {
    std::mt19937 rng;
    Eigen::Vector3d centre;
    double shell, aim;
    RandomRays(unsigned seed, const Eigen::Vector3d& c, double s, double a)
        : rng(seed), centre(c), shell(s), aim(a) {}
    void next(Vec3f& o, Vec3f& d, float& tfar) {
        std::normal_distribution<double> g;
        std::uniform_real_distribution<double> u(0, 1);
        const Eigen::Vector3d from =
            centre + shell * Eigen::Vector3d(g(rng), g(rng), g(rng)).normalized();
        const Eigen::Vector3d to =
            centre + aim * std::cbrt(u(rng)) * Eigen::Vector3d(g(rng), g(rng), g(rng)).normalized();
        const Eigen::Vector3d dir = (to - from).normalized();
        for (std::size_t a = 0; a < 3; ++a) {
            o[a] = static_cast<float>(from[static_cast<Eigen::Index>(a)]);
            d[a] = static_cast<float>(dir[static_cast<Eigen::Index>(a)]);
        }
        tfar = u(rng) < 0.1 ? static_cast<float>(0.5 * shell) : kInfF;
    }
};

struct Shape {
    const char* name;
    TriangleMesh mesh;
    Eigen::Vector3d centre;
    double size;
};

inline std::vector<Shape> shapes() {
    const Eigen::Vector3d c(0.01, -0.02, 0.03);
    return {{"sphere", sphereMesh(c, 0.02, 48, 96), c, 0.02},
            {"box", boxSurface(5, 0.01, c - Eigen::Vector3d::Constant(0.02)), c, 0.02},
            {"hex13", boxSurface(13, 0.04 / 12, c - Eigen::Vector3d::Constant(0.02)), c, 0.02}};
}

}  // namespace palp::kernels::rfix
