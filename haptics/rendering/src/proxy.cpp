#include "palp/haptics/rendering/proxy.h"

#include <Eigen/Geometry>
#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <limits>
#include <string>

#include "palp/base/bounds.h"
#include "palp/base/error.h"
#include "palp/base/validate.h"

namespace palp::haptics {

namespace {

/// A constraint: the offset plane n.x = d (d = surface offset + epsilon), n the unit outward
/// normal on the side the proxy came from.
struct Plane {
    Eigen::Vector3d n;
    double d;
};

/// The proxy counts as lying on an offset plane when it is within this fraction of epsilon.
constexpr double kOnPlaneFraction = 1e-3;
/// Shorter segments than this (m) are not traced: the proxy is already at its target.
constexpr double kMinSegment = 1e-15;

/// Sideways shift of the confirming reverse ray, as a fraction of epsilon: well above float
/// rounding at scene coordinates, well below the clearance the proxy keeps.
constexpr double kSideShift = 0.05;

/// A unit vector perpendicular to @p u in a direction unrelated to mesh axes.
Eigen::Vector3d sideways(const Eigen::Vector3d& u) noexcept {
    const Eigen::Vector3d g(0.5377, 0.8018, 0.2604);  // any generic direction
    Eigen::Vector3d w = u.cross(g);
    if (w.norm() < 1e-3) w = u.cross(Eigen::Vector3d(-0.7071, 0.1, 0.6998));
    return w.normalized();
}

void requireFinite(double v, const char* field, const std::string& expected, bool ok) {
    if (std::isfinite(v) && ok) return;
    throw ValueError(std::string("proxy parameter ") + field + ": expected " + expected +
                     ", found " + std::to_string(v));
}

struct Hit {
    unsigned geomId = kernels::kNoGeometry;
    unsigned primId = kernels::kNoGeometry;
    Eigen::Vector3d ng{Eigen::Vector3d::Zero()};
};

/// Closest hit of the ray x + t u, t in [0, length], against geometries of @p mask.
bool trace(const kernels::EmbreeScene& scene, const Eigen::Vector3d& x, const Eigen::Vector3d& u,
           double length, unsigned mask, Hit& hit) noexcept {
    kernels::MeshHit mh;
    if (!kernels::intersectOne(scene, x, u, 0.0f, static_cast<float>(length), mask, mh))
        return false;
    hit.geomId = mh.geomId;
    hit.primId = mh.primId;
    hit.ng = Eigen::Vector3d(mh.ngX, mh.ngY, mh.ngZ);
    return true;
}

/// The offset plane of the hit triangle, in double precision from its (float) vertices so that
/// flat faces give exact planes; Embree's Ng is the fallback. Oriented against @p u.
bool planeOf(const kernels::EmbreeScene& scene, const Hit& hit, const Eigen::Vector3d& u,
             double epsilon, Plane& plane) noexcept {
    Eigen::Vector3d ng = hit.ng;
    double offset = std::numeric_limits<double>::quiet_NaN();
    std::array<Eigen::Vector3f, 3> corners;
    if (scene.triangle(hit.geomId, hit.primId, corners)) {
        const Eigen::Vector3d a = corners[0].cast<double>(), b = corners[1].cast<double>(),
                              c = corners[2].cast<double>();
        const Eigen::Vector3d cross = (b - a).cross(c - a);
        if (cross.norm() > 0) {
            ng = cross;
            offset = cross.normalized().dot(a);
        }
    }
    const double len = ng.norm();
    if (!(len > 0) || !std::isfinite(offset)) return false;
    Eigen::Vector3d n = ng / len;
    const double nu = n.dot(u);
    if (!(std::abs(nu) > 1e-12)) return false;  // grazing: the side is unknown
    if (nu > 0) {
        n = -n;
        offset = -offset;
    }
    plane.n = n;
    plane.d = offset + epsilon;
    return true;
}

/// The point closest to @p p with n_i.x >= d_i for the @p m planes (m <= 3): the feasible
/// projection onto a subset of the planes (as equalities) nearest to p. False when none is
/// feasible (degenerate planes).
bool closestFeasible(const Eigen::Vector3d& p, const std::array<Plane, 3>& planes, int m,
                     Eigen::Vector3d& out) noexcept {
    const auto feasible = [&](const Eigen::Vector3d& x) {
        for (int i = 0; i < m; ++i) {
            const Plane& q = planes[static_cast<std::size_t>(i)];
            if (q.n.dot(x) < q.d - 1e-12) return false;
        }
        return true;
    };
    if (feasible(p)) {
        out = p;
        return true;
    }
    double best = std::numeric_limits<double>::infinity();
    const unsigned subsets = 1u << static_cast<unsigned>(m);
    for (unsigned s = 1; s < subsets; ++s) {
        std::array<int, 3> ids{};
        int k = 0;
        for (int i = 0; i < m; ++i)
            if (s & (1u << static_cast<unsigned>(i))) ids[static_cast<std::size_t>(k++)] = i;
        // x = p + sum_j lambda_j n_j with n_i.x = d_i on the subset: G lambda = d - N p.
        Eigen::Matrix3d g = Eigen::Matrix3d::Identity();
        Eigen::Vector3d r = Eigen::Vector3d::Zero();
        for (int a = 0; a < k; ++a) {
            const Plane& pa = planes[static_cast<std::size_t>(ids[static_cast<std::size_t>(a)])];
            r[a] = pa.d - pa.n.dot(p);
            for (int b = 0; b < k; ++b)
                g(a, b) =
                    pa.n.dot(planes[static_cast<std::size_t>(ids[static_cast<std::size_t>(b)])].n);
        }
        const double det = g.determinant();
        if (!(std::abs(det) > 1e-9)) continue;  // parallel planes: no unique line or point
        const Eigen::Vector3d lambda = g.inverse() * r;
        Eigen::Vector3d x = p;
        for (int a = 0; a < k; ++a)
            x += lambda[a] * planes[static_cast<std::size_t>(ids[static_cast<std::size_t>(a)])].n;
        const double dist = (x - p).squaredNorm();
        if (dist < best && feasible(x)) {
            best = dist;
            out = x;
        }
    }
    return std::isfinite(best);
}

/// t1 continuous: the last t1 with its component along n removed.
void updateFrame(const Eigen::Vector3d& n, Eigen::Vector3d& t1, Eigen::Vector3d& t2) noexcept {
    Eigen::Vector3d t = t1 - n.dot(t1) * n;
    if (t.norm() < 1e-6) t = t2 - n.dot(t2) * n;
    if (t.norm() < 1e-6) {
        const Eigen::Vector3d axis =
            std::abs(n.x()) < 0.9 ? Eigen::Vector3d::UnitX() : Eigen::Vector3d::UnitY();
        t = axis - n.dot(axis) * n;
    }
    t1 = t.normalized();
    t2 = n.cross(t1);
}

}  // namespace

void validateProxyParams(const ProxyParams& p) {
    requireWithin("proxy parameter staticFriction", p.staticFriction, bounds::kFriction);
    requireFinite(p.dynamicFriction, "dynamicFriction",
                  "a finite value in [0, staticFriction = " + formatValue(p.staticFriction) + "]",
                  p.dynamicFriction >= 0 && p.dynamicFriction <= p.staticFriction);
    requireWithin("proxy parameter epsilon", p.epsilon, bounds::kSpacing);
    if (p.maxIterations < 1 || p.maxIterations > 16)
        throw ValueError("proxy parameter maxIterations: expected 1..16, found " +
                         std::to_string(p.maxIterations));
}

Proxy::Proxy(const kernels::EmbreeScene& scene, const ProxyParams& params)
    : mScene(&scene), mParams(params) {}

void Proxy::reset(const Eigen::Vector3d& position) noexcept {
    mState.position = position;
    mState.velocity.setZero();
    mState.contactCount = 0;
    mState.sticking = false;
    mState.queries = 0;
}

void Proxy::carry(const Eigen::Vector3d& position) noexcept {
    mState.position = position;
    mState.velocity.setZero();
    mState.queries = 0;
}

void Proxy::restore(const ProxyState& state) noexcept {
    mState = state;
    mState.velocity.setZero();
    mState.queries = 0;
}

const ProxyState& Proxy::update(const Eigen::Vector3d& probe,
                                const Eigen::Vector3d& tangentialForce, double stiffness, double dt,
                                double stepStiffness, double springStepStiffness) noexcept {
    if (!(stepStiffness > stiffness)) stepStiffness = stiffness;
    if (!(springStepStiffness > 0) || springStepStiffness > stepStiffness)
        springStepStiffness = stepStiffness;
    springStepStiffness = std::max(springStepStiffness, stiffness);
    if (!probe.allFinite() || !tangentialForce.allFinite() || !std::isfinite(stiffness) ||
        !(stiffness > 0) || !std::isfinite(dt) || !(dt > 0))
        return mState;
    const Eigen::Vector3d start = mState.position;
    const ProxyState before = mState;
    mState.sticking = false;
    mState.contactCount = 0;
    mState.queries = 0;
    if (mScene->empty() || !mScene->committed() || !start.allFinite()) {
        mState.position = probe;
        mState.velocity =
            start.allFinite() ? Eigen::Vector3d((probe - start) / dt) : Eigen::Vector3d::Zero();
        return mState;
    }

    const kernels::EmbreeScene& scene = *mScene;
    const double eps = mParams.epsilon;
    const double onTol = kOnPlaneFraction * eps;
    std::array<Plane, 3> planes{};
    int m = 0;
    Eigen::Vector3d x = start;
    Eigen::Vector3d target = probe;
    bool frictionDone = false;
    const int maxSegments = std::clamp(mParams.maxIterations, 1, 16) + 1;
    for (int segment = 0; segment < maxSegments; ++segment) {
        const Eigen::Vector3d seg = target - x;
        const double len = seg.norm();
        if (!(len > kMinSegment)) break;
        const Eigen::Vector3d u = seg / len;
        Hit hit;
        ++mState.queries;
        // Traced epsilon past the target, so a target just short of a surface is a contact.
        bool blocked = trace(scene, x, u, len + eps, mParams.surfaceMask, hit);
        Plane plane;
        if (blocked && !planeOf(scene, hit, u, eps, plane)) break;
        // Where the segment takes the proxy: the target, or the hit's offset plane (the proxy
        // stays when already on it or below it).
        const auto advance = [&](const Plane& q) {
            const double above = q.n.dot(x) - q.d;
            return above > onTol ? std::min(above / -q.n.dot(u), len) : 0.0;
        };
        double reach = blocked ? advance(plane) : len;
        // Embree's ray test is not watertight: a ray through a shared edge can slip between
        // two triangles, in both directions. The move is confirmed by a reverse ray on a line
        // shifted sideways by kSideShift epsilon (so it crosses such an edge inside a face);
        // a surface it finds blocks like a forward hit.
        if (reach > kMinSegment) {
            Hit back;
            ++mState.queries;
            const Eigen::Vector3d side = kSideShift * eps * sideways(u);
            if (trace(scene, x + reach * u + side, -u, reach, mParams.surfaceMask, back)) {
                if (!planeOf(scene, back, u, eps, plane)) break;
                blocked = true;
                reach = std::min(advance(plane), reach);
            }
        }
        if (!blocked) {
            x = target;
            break;
        }
        x += reach * u;
        bool known = false;
        for (int i = 0; i < m; ++i) {
            const Plane& q = planes[static_cast<std::size_t>(i)];
            known = known || (q.n.dot(plane.n) > 1.0 - 1e-12 && std::abs(q.d - plane.d) <= onTol);
        }
        if (known || m == 3) break;  // no progress possible: stay
        planes[static_cast<std::size_t>(m++)] = plane;
        if (!frictionDone) {
            // Coulomb friction on the first contact plane.
            frictionDone = true;
            const Eigen::Vector3d& n = plane.n;
            const Eigen::Vector3d ftExtra = tangentialForce - n.dot(tangentialForce) * n;
            const Eigen::Vector3d spring = stiffness * (probe - x);
            const Eigen::Vector3d f = spring + ftExtra;
            const double normal = std::max(-n.dot(f), 0.0);
            const Eigen::Vector3d ft = f - n.dot(f) * n;
            const double ftNorm = ft.norm();
            if (ftNorm <= mParams.staticFriction * normal) {
                mState.sticking = true;
                break;
            }
            // The damped step of the whole force, (k a + F_t) / k_step with a = f_spring,t / k
            // the way to the probe's projection, plus (k / k_spring - k / k_step) a, so that the
            // spring's pull moves the proxy as with k_spring (k: as in plain AVC) and the extra
            // force (which varies quickly with position) is damped by k_step. Where the extra force
            // opposes the pull, the rest only goes as far as the two balance along a (t* = |a| +
            // F_t . a / (k |a|), none when t* <= 0): the step then still lowers the potential
            // 1/2 k |x_pb - x|^2 - F_t . x, which adding all of a would not. Friction takes the
            // same share of every part.
            const double slip = std::max(ftNorm - mParams.dynamicFriction * normal, 0.0) / ftNorm;
            const Eigen::Vector3d a = (spring - n.dot(spring) * n) / stiffness;
            const double aNorm = a.norm();
            const double along = aNorm > 0 ? ftExtra.dot(a) / (stiffness * aNorm) : 0.0;
            const double rest = along >= 0 ? 1.0 : std::max(aNorm + along, 0.0) / aNorm;
            const double damped = stiffness / stepStiffness;
            const double springShare = stiffness / springStepStiffness;
            target = x + slip * (damped * a + ftExtra / stepStiffness +
                                 (springShare - damped) * rest * a);
            target += (plane.d - n.dot(target)) * n;  // onto the offset plane
        } else if (!closestFeasible(target, planes, m, target)) {
            break;
        }
    }

    // A proxy that started in contact moves only where its potential, the spring's
    // 1/2 k |x_pb - x|^2 less the extra force's work F_t . (x - start), is not higher than where
    // it started. Every slide and projection above lowers it; what raises it is only the path
    // through more facets than the three planes held: in a pit of four or more facets (the
    // bottom of a pressed dimple on deformable tissue) each triple of offset planes meets at
    // its own point, up to epsilon apart, and which triple a tick finds depends on the facet
    // the first ray happens to cross, so a held proxy hopped between them every tick (a held
    // press's force changed by 3 % a tick, at 250-500 Hz). It then stays, in its contact.
    if (before.contactCount > 0) {
        const double was = 0.5 * stiffness * (start - probe).squaredNorm();
        const double now =
            0.5 * stiffness * (x - probe).squaredNorm() - tangentialForce.dot(x - start);
        if (!(now <= was)) {
            const int queries = mState.queries;
            mState = before;
            mState.sticking = true;
            mState.velocity.setZero();
            mState.queries = queries;
            return mState;
        }
    }

    // Active: planes whose clearance shell holds the proxy (on the offset plane, or between it
    // and the surface: where a stuck proxy stays when a neighbouring facet rises closer than
    // epsilon, e.g. at every concave facet junction of a noisy iso-surface) and that the probe
    // presses into. A proxy farther below a plane than epsilon has left it (past a convex edge).
    for (int i = 0; i < m; ++i) {
        const Plane& q = planes[static_cast<std::size_t>(i)];
        const double above = q.n.dot(x) - q.d;
        if (above <= onTol && above >= -eps - onTol && q.n.dot(probe) < q.d)
            mState.normals[static_cast<std::size_t>(mState.contactCount++)] = q.n;
    }
    if (mState.contactCount == 0) mState.sticking = false;
    if (mState.contactCount > 0) updateFrame(mState.normals[0], mState.tangent1, mState.tangent2);
    mState.velocity = (x - start) / dt;
    mState.position = x;
    return mState;
}

}  // namespace palp::haptics
