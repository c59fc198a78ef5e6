#include "palp/haptics/rendering/coupling.h"

#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <span>
#include <string>
#include <utility>

#include "palp/base/bounds.h"
#include "palp/base/error.h"
#include "palp/base/validate.h"
#include "palp/haptics/tissue/deformable.h"

namespace palp::haptics {

namespace detail {

/// Where AVCEC's rays leave and along what (docs/algorithms.md section 3, "The rays' tilt").
/// Without a limit, or with the probe straight under the proxy: from x_py along d. With one,
/// d's tilt theta from the contact's inward normal u (Coupling::inwardNormal) becomes
/// f(theta) = theta_c tanh(theta / theta_c), in d's azimuth w, and the rays leave from the
/// point of the contact plane whose ray along that axis passes through the probe,
/// o = x_py + lambda w with lambda = D_t - D_n tan f(theta) (D_t, D_n: the probe's offset
/// along w and u). A lagging proxy then turns the rays about the probe, as without a limit,
/// but at most theta_c: they look under the probe, not ahead of it.
struct RayAxis {
    Eigen::Vector3d origin;
    Eigen::Vector3d dir;
    bool limited = false;
    Eigen::Vector3d u{Eigen::Vector3d::Zero()}, w{Eigen::Vector3d::Zero()},
        azimuth{Eigen::Vector3d::Zero()};
    double axisTilt = 0, slope = 1, lambda = 0, Dt = 0, Dn = 0;
};

}  // namespace detail

namespace {

using detail::RayAxis;

bool finite3(const Eigen::Vector3d& v) noexcept {
    return std::isfinite(v.x()) && std::isfinite(v.y()) && std::isfinite(v.z());
}

/// A bound on the tangential curvature (N/m) of E's stiffness terms as the proxy moves: the
/// surface stencil's second differences of k times D^2 / 2, the spherical stencil's times 1/2
/// (a proxy step dx turns d by dx / D), and the cross terms of the gradients with D.
double tangentialCurvature(const kernels::RayBundle& b,
                           const std::array<double, kernels::kMaxBundleRays>& k, double D,
                           const CouplingOutput& out) noexcept {
    auto bound = [&](bool sphere, double s) {
        auto at = [&](int i, int j) {
            return k[static_cast<std::size_t>(sphere ? b.sphereRay(i, j) : b.surfaceRay(i, j))];
        };
        const double kxx = at(1, 0) - 2 * at(0, 0) + at(-1, 0);
        const double kyy = at(0, 1) - 2 * at(0, 0) + at(0, -1);
        const double kxy = 0.25 * (at(1, 1) - at(1, -1) - at(-1, 1) + at(-1, -1));
        return (std::abs(kxx) + std::abs(kyy) + 2 * std::abs(kxy)) / (s * s);
    };
    const double c = 0.5 * D * D * bound(false, b.surfaceOffset) + 0.5 * bound(true, b.sobelAngle) +
                     D * std::hypot(out.surface.g1, out.surface.g2) +
                     std::hypot(out.sphere.g1, out.sphere.g2);
    return std::isfinite(c) ? c : 0.0;
}

RayAxis rayAxis(const Eigen::Vector3d& proxy, const Eigen::Vector3d& delta, double D,
                const Eigen::Vector3d& inward, double maxTilt) noexcept {
    RayAxis a{proxy, delta / D};
    if (!(maxTilt < kNoRayTiltLimit)) return a;
    const double un = inward.norm();
    if (!(un > 0.5)) return a;  // no contact frame
    const Eigen::Vector3d u = inward / un;
    const double Dn = delta.dot(u);
    Eigen::Vector3d w = delta - Dn * u;
    const double Dt = w.norm();
    // Pulling out of the surface, or straight down (f(theta) = theta to 1e-7 there): along d.
    if (!(Dn > 0) || !(Dt > 1e-3 * D)) return a;
    w /= Dt;
    const double th = std::tanh(std::atan2(Dt, Dn) / maxTilt);
    a.axisTilt = maxTilt * th;
    a.slope = 1 - th * th;  // f'(theta)
    a.lambda = Dt - Dn * std::tan(a.axisTilt);
    a.origin = proxy + a.lambda * w;
    a.dir = std::cos(a.axisTilt) * u + std::sin(a.axisTilt) * w;
    a.u = u;
    a.w = w;
    a.azimuth = u.cross(w);
    a.Dt = Dt;
    a.Dn = Dn;
    a.limited = true;
    return a;
}

/// grad_pb k with the tilt limit (RayAxis), k = k(o, axis): @p G is the spherical stencil's
/// gradient (per radian, perpendicular to the axis: the rays turned about o), @p S the surface
/// stencil's (per metre, in the contact plane: o moved), both in the world. The probe moves the
/// axis's tilt by f'(theta) d theta, its azimuth by dx_a / D_t, and o by d lambda along w and
/// lambda dx_a / D_t along the azimuth.
Eigen::Vector3d limitedProbeGradient(const RayAxis& a, const Eigen::Vector3d& G,
                                     const Eigen::Vector3d& S, double D) noexcept {
    const double c = std::cos(a.axisTilt), sn = std::sin(a.axisTilt);
    const Eigen::Vector3d axisPolar = -sn * a.u + c * a.w;
    const double Gp = G.dot(axisPolar), Ga = G.dot(a.azimuth);
    const double Sw = S.dot(a.w), Sa = S.dot(a.azimuth);
    const double D2 = D * D, sec2 = 1 / (c * c);
    // d theta / d D_t = D_n / D^2, d theta / d D_n = -D_t / D^2.
    const double thetaDt = a.Dn / D2, thetaDn = -a.Dt / D2;
    const double lambdaDt = 1 - a.Dn * sec2 * a.slope * thetaDt;
    const double lambdaDn = -sn / c - a.Dn * sec2 * a.slope * thetaDn;
    const double alongW = Gp * a.slope * thetaDt + Sw * lambdaDt;
    const double alongU = Gp * a.slope * thetaDn + Sw * lambdaDn;
    const double alongA = (Ga * sn + Sa * a.lambda) / a.Dt;
    return alongW * a.w + alongU * a.u + alongA * a.azimuth;
}

}  // namespace

void validateCouplingParams(const CouplingParams& p) {
    if (p.mode != CouplingMode::VC && p.mode != CouplingMode::AVC && p.mode != CouplingMode::AVCEC)
        throw ValueError("coupling mode: expected VC, AVC or AVCEC, found value " +
                         std::to_string(static_cast<int>(p.mode)));
    if (p.source != RaySource::Mesh && p.source != RaySource::VolumeFirstHit &&
        p.source != RaySource::VolumeAccumulate)
        throw ValueError(
            "coupling source: expected Mesh, VolumeFirstHit or VolumeAccumulate, found value " +
            std::to_string(static_cast<int>(p.source)));
    requireWithin("coupling baseStiffness", p.baseStiffness, bounds::kPositiveStiffness);
    requireWithin("coupling referenceLength", p.referenceLength, bounds::kLength);
    requireWithin("coupling maxMultiplier", p.maxMultiplier, bounds::kMultiplier);
    requireWithin("coupling maxStiffness", p.maxStiffness, bounds::kPositiveStiffness);
    if (!(std::isfinite(p.maxStiffness) && p.maxStiffness >= p.baseStiffness))
        throwExpected("coupling maxStiffness",
                      "a finite value >= baseStiffness (" + formatValue(p.baseStiffness) + " N/m)",
                      formatValue(p.maxStiffness));
    requireWithin("coupling damping", p.damping, bounds::kDamping);
    requireWithin("coupling minDistance", p.minDistance, bounds::kSpacing);
    requireWithin("coupling maxRayTilt", p.maxRayTilt, bounds::kRayTilt);
    if (!(std::isfinite(p.stiffnessTimeConstant) && p.stiffnessTimeConstant >= 0 &&
          p.stiffnessTimeConstant <= 1))
        throwExpected("coupling stiffnessTimeConstant", "a time in [0, 1] s",
                      formatValue(p.stiffnessTimeConstant));
    if (p.source == RaySource::Mesh && p.hardMask == 0)
        throw ValueError(
            "coupling hardMask: expected at least one mask bit for the Mesh source, "
            "found 0");
    kernels::validateBundleParams(p.bundle);
    kernels::validateFirstHitParams(p.firstHit);
    kernels::validateAccumulateParams(p.accumulate);
    // Every tick marches each volume ray length / step samples: keep a tick's work bounded.
    for (const auto& [what, step] : {std::pair{"first-hit step", p.firstHit.step},
                                     std::pair{"accumulate step", p.accumulate.step}}) {
        if (p.bundle.length / step > kMaxRaySamples) {
            throwExpected(std::string("coupling ") + what,
                          "at least bundle length / " + std::to_string(kMaxRaySamples) + " = " +
                              formatValue(p.bundle.length / kMaxRaySamples) + " m",
                          formatValue(step) + " m");
        }
    }
}

double stiffnessMultiplier(const CouplingParams& params, double rayLength) noexcept {
    if (std::isnan(rayLength)) return 1.0;
    if (!(rayLength > 0)) return params.maxMultiplier;
    return std::clamp(params.referenceLength / rayLength, 1.0, params.maxMultiplier);
}

Coupling::Coupling(const kernels::VolumeView* volume, const kernels::EmbreeScene* hardMeshes,
                   const CouplingParams& params, const kernels::EmbreeScene* movingMeshes)
    : mVolume(volume), mMeshes(hardMeshes), mMoving(movingMeshes), mParams(params) {
    validateCouplingParams(params);
    if (params.mode != CouplingMode::VC && !sourceAvailable()) {
        const char* what = params.source == RaySource::Mesh
                               ? "coupling source Mesh: expected a committed, non-empty Embree "
                                 "scene of hard meshes, found "
                               : "coupling source Volume*: expected a volume view, found ";
        const bool none =
            params.source == RaySource::Mesh ? hardMeshes == nullptr : volume == nullptr;
        throw ValueError(std::string(what) + (none ? "none" : "an empty or uncommitted scene"));
    }
}

void Coupling::setParams(const CouplingParams& params) noexcept { mParams = params; }

bool Coupling::sourceAvailable() const noexcept {
    switch (mParams.source) {
        case RaySource::Mesh:
            return (mMeshes != nullptr && !mMeshes->empty() && mMeshes->committed()) ||
                   mMoving != nullptr;
        case RaySource::VolumeFirstHit:
        case RaySource::VolumeAccumulate:
            return mVolume != nullptr;
    }
    return false;
}

void Coupling::beginTick(double dtSeconds) noexcept {
    const double tau = mParams.stiffnessTimeConstant;
    mTicking = tau > 0 && std::isfinite(dtSeconds) && dtSeconds > 0;
    mKGain = mTicking ? -std::expm1(-dtSeconds / tau) : 1.0;
    mKStart = mKLast;
    mKStartValid = mKLastValid;
    mEnergyForceStart = mEnergyForceLast;
}

double Coupling::filtered(double kRays) const noexcept {
    if (!mTicking || !mKStartValid || !std::isfinite(kRays)) return kRays;
    return mKStart + mKGain * (kRays - mKStart);
}

void Coupling::compute(const Eigen::Vector3d& proxy, const Eigen::Vector3d& probe,
                       const Eigen::Vector3d& proxyVelocity, const Eigen::Vector3d& probeVelocity,
                       const Eigen::Vector3d& tangent1, const Eigen::Vector3d& tangent2,
                       CouplingOutput& out) noexcept {
    out = CouplingOutput{};
    const CouplingParams& p = mParams;
    mKLastValid = false;         // until this call computes a k (no contact restarts the filter)
    mEnergyForceLast.setZero();  // until an AVCEC call computes the term
    if (!finite3(proxy) || !finite3(probe) || !finite3(proxyVelocity) || !finite3(probeVelocity) ||
        !finite3(tangent1) || !finite3(tangent2))
        return;
    const Eigen::Vector3d delta = probe - proxy;
    const double D = delta.norm();
    if (!std::isfinite(D) || !(D >= p.minDistance)) return;
    const Eigen::Vector3d d = delta / D;
    out.distance = D;
    const Eigen::Vector3d dampingForce = p.damping * (proxyVelocity - probeVelocity);

    RayAxis axis{proxy, d};
    const bool rays = castRays(proxy, delta, D, tangent1, tangent2, axis, mBundle);
    if (!rays) {
        mBundle.count = 0;
        mBundle.valid = false;
        out.stiffness = std::min(p.baseStiffness, p.maxStiffness);
        out.force = -out.stiffness * D * d + dampingForce;
        out.energy = 0.5 * out.stiffness * D * D;
        out.stepStiffness = out.stiffness;
        return;
    }
    const bool ec = p.mode == CouplingMode::AVCEC;
    // AVC needs only the centre and the ring: the stencil rays are not traced at all.
    if (!ec) mBundle.count = 1 + mBundle.ringCount;
    const int n = mBundle.count;
    std::array<double, kernels::kMaxBundleRays> k{};
    double centreLength = 0;
    traceStiffness(mBundle, n, k, centreLength);
    const std::span<const double> perRay(k.data(), static_cast<std::size_t>(n));

    out.rays = n;
    out.rayLength = centreLength;
    const double kRays = kernels::lowPass(mBundle, perRay);
    out.stiffness = filtered(kRays);
    mKLast = out.stiffness;
    mKLastValid = std::isfinite(mKLast);
    out.force = -out.stiffness * D * d + dampingForce;
    out.energy = 0.5 * out.stiffness * D * D;
    out.stepStiffness = std::max(out.stiffness, kRays);
    if (!ec) return;

    // E = 1/2 k D^2: the probe gradient adds -1/2 D (g1 e1 + g2 e2), the proxy gradient
    // -1/2 D^2 (gs1 t1 + gs2 t2). Both stencils read the raw per-ray k (centre ray in the middle).
    out.sphere = kernels::sphericalSobel(mBundle, perRay);
    out.surface = kernels::surfaceSobel(mBundle, perRay);
    out.energyForce = -0.5 * D * (out.sphere.g1 * mBundle.e1 + out.sphere.g2 * mBundle.e2);
    out.proxyForce = -0.5 * D * D * (out.surface.g1 * mBundle.t1 + out.surface.g2 * mBundle.t2);
    if (mFramed) {
        // The stencils' axes were R^T e and R^T t: back to the world.
        out.energyForce = mFrame * out.energyForce;
        out.proxyForce = mFrame * out.proxyForce;
    }
    if (axis.limited) {
        // The probe moves the rays' origin as well as their axis (RayAxis).
        const Eigen::Vector3d G = -2 / D * out.energyForce;
        const Eigen::Vector3d S = -2 / (D * D) * out.proxyForce;
        out.energyForce = -0.5 * D * D * limitedProbeGradient(axis, G, S, D);
    }
    // Deformable tissue: the term the skin it pushes changes is low-passed as k is.
    if (mTicking && mKStartValid)
        out.energyForce = mEnergyForceStart + mKGain * (out.energyForce - mEnergyForceStart);
    mEnergyForceLast = out.energyForce;
    out.force += out.energyForce;
    // The proxy's step is bounded by the rays' k as well as the filtered one (the field it
    // moves in is the rays').
    out.stepStiffness = std::max(out.stiffness, kRays) + tangentialCurvature(mBundle, k, D, out);
}

bool Coupling::castRays(const Eigen::Vector3d& proxy, const Eigen::Vector3d& delta, double D,
                        const Eigen::Vector3d& tangent1, const Eigen::Vector3d& tangent2,
                        RayAxis& axis, kernels::RayBundle& out) noexcept {
    const CouplingParams& p = mParams;
    axis = p.mode == CouplingMode::AVCEC && p.maxRayTilt < kNoRayTiltLimit
               ? rayAxis(proxy, delta, D, inwardNormal(proxy, tangent1, tangent2), p.maxRayTilt)
               : RayAxis{proxy, delta / D};
    if (p.mode == CouplingMode::VC || !sourceAvailable()) return false;
    // Deformable tissue: the rays leave in the material frame at the contact.
    const Eigen::Matrix3d Rt = mFrame.transpose();
    return mFramed
               ? kernels::generateBundle(axis.origin, Rt * axis.dir, Rt * tangent1, Rt * tangent2,
                                         p.bundle, out)
               : kernels::generateBundle(axis.origin, axis.dir, tangent1, tangent2, p.bundle, out);
}

Eigen::Vector3d Coupling::inwardNormal(const Eigen::Vector3d& proxy,
                                       const Eigen::Vector3d& tangent1,
                                       const Eigen::Vector3d& tangent2) const noexcept {
    const Eigen::Vector3d facet = -tangent1.cross(tangent2);
    // A rigid scan: the normal of its iso-surface, continuous across the proxy mesh's facets
    // (their normals jump by degrees between 0.5 mm facets, and a ray axis that jumps with
    // them jumps k: the proxy then met walls of E at facet edges on the head CT and stuck,
    // the force rising to the device's limit). The gradient of the trilinear volume by central
    // differences two voxels apart, on the facet's side.
    if (mVolume == nullptr || mDeformation != nullptr || mParams.source == RaySource::Mesh)
        return facet;
    const Eigen::Vector3d x = mVolume->indexFromWorld(proxy);
    Eigen::Vector3d g;
    for (int a = 0; a < 3; ++a) {
        Eigen::Vector3d e = Eigen::Vector3d::Zero();
        e[a] = 2;
        const Eigen::Vector3d hi = x + e, lo = x - e;
        g[a] = double(mVolume->sampleIndex(hi.x(), hi.y(), hi.z())) -
               double(mVolume->sampleIndex(lo.x(), lo.y(), lo.z()));
    }
    const double gn = g.norm();
    if (!(gn > 0) || !std::isfinite(gn) || !(g.dot(facet) > 0)) return facet;
    return g / gn;
}

void Coupling::traceStiffness(kernels::RayBundle& bundle, int n,
                              std::array<double, kernels::kMaxBundleRays>& k,
                              double& centreLength) noexcept {
    const CouplingParams& p = mParams;
    bundle.count = n;
    auto stiffness = [&](double length) {
        return std::min(p.baseStiffness * stiffnessMultiplier(p, length), p.maxStiffness);
    };
    // Deformable scenes: the volume is sampled where the tissue was at rest.
    const bool mapped = mDeformation != nullptr && p.source != RaySource::Mesh;
    const kernels::RayBundle& traced = mapped ? restBundle(bundle, n) : bundle;
    const auto length = [&](int r, double t, bool found) {
        return mapped && found ? currentLength(bundle, r, t) : t;
    };
    switch (p.source) {
        case RaySource::Mesh: {
            const bool fixed = mMeshes != nullptr && !mMeshes->empty() && mMeshes->committed();
            if (fixed) kernels::traceBundle(*mMeshes, bundle, p.hardMask, mHits);
            if (mMoving != nullptr) {
                kernels::traceBundle(*mMoving, bundle, p.hardMask, fixed ? mMovingHits : mHits);
                if (fixed) {
                    // Per ray, the nearer of the two scenes' hits.
                    for (int r = 0; r < mHits.count && r < mMovingHits.count; ++r) {
                        const auto i = static_cast<std::size_t>(r);
                        if (mMovingHits.t[i] < mHits.t[i]) {
                            mHits.t[i] = mMovingHits.t[i];
                            mHits.hit[i] = mMovingHits.hit[i];
                            mHits.geomId[i] = mMovingHits.geomId[i];
                        }
                    }
                }
            }
            for (int r = 0; r < mHits.count; ++r)
                k[static_cast<std::size_t>(r)] = stiffness(mHits.t[static_cast<std::size_t>(r)]);
            centreLength = mHits.count > 0 ? mHits.t[0] : p.bundle.length;
            break;
        }
        case RaySource::VolumeFirstHit: {
            kernels::traceFirstHit(*mVolume, traced, p.firstHit, mHits);
            for (int r = 0; r < mHits.count; ++r) {
                const auto i = static_cast<std::size_t>(r);
                const double L = length(r, mHits.t[i], mHits.hit[i] != 0);
                k[i] = stiffness(L);
                if (r == 0) centreLength = L;
            }
            if (mHits.count == 0) centreLength = p.bundle.length;
            break;
        }
        case RaySource::VolumeAccumulate:
            kernels::traceAccumulate(*mVolume, traced, p.accumulate, mAccum);
            for (int r = 0; r < mAccum.count; ++r) {
                const auto i = static_cast<std::size_t>(r);
                const double L = length(r, mAccum.t[i], mAccum.stopped[i] != 0);
                k[i] = stiffness(L);
                if (r == 0) centreLength = L;
            }
            if (mAccum.count == 0) centreLength = p.bundle.length;
            break;
    }
}

const kernels::RayBundle& Coupling::restBundle(const kernels::RayBundle& bundle, int n) noexcept {
    mRestBundle = bundle;
    for (int r = 0; r < n; ++r) {
        const auto i = static_cast<std::size_t>(r);
        const Eigen::Vector3d o(bundle.ox[i], bundle.oy[i], bundle.oz[i]);
        const Eigen::Vector3d dir(bundle.dx[i], bundle.dy[i], bundle.dz[i]);
        const Eigen::Vector3d from = mDeformation->restFromCurrent(o);
        const Eigen::Vector3d to = mDeformation->restFromCurrent(o + bundle.length[i] * dir);
        const Eigen::Vector3d chord = to - from;
        const double len = chord.norm();
        // A degenerate chord (a ray shorter than the map's tolerance) keeps the current ray.
        if (!from.allFinite() || !(len > 1e-9) || !std::isfinite(len)) continue;
        const Eigen::Vector3d unit = chord / len;
        mRestBundle.ox[i] = static_cast<float>(from.x());
        mRestBundle.oy[i] = static_cast<float>(from.y());
        mRestBundle.oz[i] = static_cast<float>(from.z());
        mRestBundle.dx[i] = static_cast<float>(unit.x());
        mRestBundle.dy[i] = static_cast<float>(unit.y());
        mRestBundle.dz[i] = static_cast<float>(unit.z());
        mRestBundle.length[i] = static_cast<float>(len);
    }
    return mRestBundle;
}

double Coupling::currentLength(const kernels::RayBundle& bundle, int r,
                               double tRest) const noexcept {
    const auto i = static_cast<std::size_t>(r);
    const kernels::RayBundle& b = mRestBundle;
    const Eigen::Vector3d at = Eigen::Vector3d(b.ox[i], b.oy[i], b.oz[i]) +
                               tRest * Eigen::Vector3d(b.dx[i], b.dy[i], b.dz[i]);
    const Eigen::Vector3d now = mDeformation->currentFromRest(at);
    const double L = (now - Eigen::Vector3d(bundle.ox[i], bundle.oy[i], bundle.oz[i])).norm();
    return std::isfinite(L) ? std::min(L, static_cast<double>(bundle.length[i])) : tRest;
}

double Coupling::storedEnergy(const Eigen::Vector3d& proxy, const Eigen::Vector3d& probe,
                              const Eigen::Vector3d& tangent1,
                              const Eigen::Vector3d& tangent2) noexcept {
    const CouplingParams& p = mParams;
    if (!finite3(proxy) || !finite3(probe) || !finite3(tangent1) || !finite3(tangent2)) return 0;
    const Eigen::Vector3d delta = probe - proxy;
    const double D = delta.norm();
    if (!std::isfinite(D) || !(D >= p.minDistance)) return 0;
    double k = std::min(p.baseStiffness, p.maxStiffness);
    RayAxis axis{proxy, delta / D};
    const bool rays = castRays(proxy, delta, D, tangent1, tangent2, axis, mProbeBundle);
    if (rays) {
        std::array<double, kernels::kMaxBundleRays> perRay{};
        double centreLength = 0;
        const int n = 1 + mProbeBundle.ringCount;
        traceStiffness(mProbeBundle, n, perRay, centreLength);
        k = filtered(kernels::lowPass(
            mProbeBundle, std::span<const double>(perRay.data(), static_cast<std::size_t>(n))));
    }
    return 0.5 * k * D * D;
}

const char* couplingModeName(CouplingMode mode) noexcept {
    switch (mode) {
        case CouplingMode::VC:
            return "vc";
        case CouplingMode::AVC:
            return "avc";
        case CouplingMode::AVCEC:
            return "avcec";
    }
    return "?";
}

const char* raySourceName(RaySource source) noexcept {
    switch (source) {
        case RaySource::Mesh:
            return "mesh";
        case RaySource::VolumeFirstHit:
            return "first-hit";
        case RaySource::VolumeAccumulate:
            return "accumulate";
    }
    return "?";
}

}  // namespace palp::haptics
