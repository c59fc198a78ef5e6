#pragma once
/// @file
/// Virtual coupling between proxy and probe: plain (VC), anisotropic (AVC, docs/algorithms.md
/// section 2) and anisotropic with energy conservation (AVCEC, section 3).

#include <Eigen/Core>
#include <array>

#include "palp/kernels/embree_scene.h"
#include "palp/kernels/ray_bundle.h"
#include "palp/kernels/volume_ray.h"

namespace palp::haptics {

class DeformableBody;

enum class CouplingMode {
    VC,     ///< k = baseStiffness, no rays
    AVC,    ///< k = baseStiffness * m(L) from the centre ray (low-passed over the ring)
    AVCEC,  ///< AVC plus the spherical (probe) and surface (proxy) energy terms
};

/// "vc", "avc" or "avcec". @par Real-time noexcept.
const char* couplingModeName(CouplingMode mode) noexcept;

/// Where the ray length L comes from.
enum class RaySource {
    Mesh,              ///< closest hit against the hard meshes (mask hardMask)
    VolumeFirstHit,    ///< first crossing of firstHit.threshold in the volume
    VolumeAccumulate,  ///< where the integral of accumulate.sigma reaches accumulate.tauStop
};

/// "mesh", "first-hit" or "accumulate". @par Real-time noexcept.
const char* raySourceName(RaySource source) noexcept;

/// CouplingParams::maxRayTilt that never limits the rays' direction.
inline constexpr double kNoRayTiltLimit = 1.5707963267948966;

/// Coupling settings. Validate with validateCouplingParams() at set-up; all switchable at run
/// time through Coupling::setParams().
struct CouplingParams {
    CouplingMode mode = CouplingMode::AVCEC;
    RaySource source = RaySource::VolumeFirstHit;
    kernels::BundleParams bundle;  ///< L_max (bundle.length), ring, delta, h
    kernels::FirstHitParams firstHit;
    kernels::AccumulateParams accumulate;
    unsigned hardMask = kernels::kMaskBone | kernels::kMaskPlate;  ///< Mesh source targets
    double baseStiffness = 300;     ///< k_s, N/m: stiffness of the surface itself
    double referenceLength = 5e-3;  ///< L_ref, m: m(L) = clamp(L_ref / L, 1, maxMultiplier)
    double maxMultiplier = 8;       ///< m_max
    double maxStiffness = 2400;     ///< k_max, N/m: k is always clamped here
    double damping = 0;             ///< b, N s/m, on v_py - v_pb
    double minDistance = 1e-6;      ///< eps, m: no ray and no force below this D
    /// tau, s: on deformable tissue (a session that starts each tick with
    /// Coupling::beginTick()), k is low-passed over ticks, k_n = k_(n-1) + (1 - e^(-dt/tau))
    /// (k_rays - k_(n-1)), and so is AVCEC's spherical term (energyForce, the same filter on
    /// the vector). The tissue carries the proxy, so k (a function of where the proxy
    /// sits) and the force that moves the tissue form a loop; with bone under a thin scalp it
    /// alternated every tick (300 / 1,020 N/m, 0.35 / 2.3 N on the head CT), and the spherical
    /// term, unfiltered, switched on and off with the skin it pushed (the proxy's path 4.7x
    /// the hand's). 5 ms passes what a hand feels of k (a bone edge crossed at 100 mm/s:
    /// 0.5 mm). 0: none. Rigid scenes (no beginTick()) use k_rays and the raw term.
    double stiffnessTimeConstant = 5e-3;
    /// theta_c, rad, AVCEC only: the rays' largest tilt from the contact's inward normal
    /// (-(t1 x t2); on a rigid scan the scan's own, its gradient). d's tilt theta becomes theta_c
    /// tanh(theta / theta_c), and the rays leave from the contact plane's point whose ray along
    /// that axis passes through the probe (the proxy itself when theta is small), so they look
    /// under the probe. Without it (pi / 2, the thesis's rays from x_py along d) a proxy held back
    /// by the spherical term's reaction tilts d 40-60 degrees, and the rays, 10-30 mm long, pass
    /// the far side of a narrow plate or beside a bone before the probe does (docs/algorithms.md
    /// section 3, "The rays' tilt"). AVC keeps d: its hidden box is found by looking under the
    /// plate along the sweep.
    double maxRayTilt = 0.05;
};

/// @throw palp::ValueError naming the field (non-finite or non-positive stiffness, lengths,
///        maxMultiplier < 1, maxStiffness < baseStiffness, negative damping, an unknown mode or
///        source, hardMask 0 with the Mesh source, and the bundle, first-hit and accumulate
///        parameters through their own validators, whatever the source).
void validateCouplingParams(const CouplingParams& params);

/// Most samples a volume ray may march per tick (bundle length / step): 40 mm at 1 um, or a
/// 300 mm head at 3 um; a coupling asking for more is refused at set-up.
inline constexpr int kMaxRaySamples = 100000;

/// The stiffness multiplier m(L) = clamp(L_ref / L, 1, m_max) (m_max for L <= 0, 1 for a NaN
/// length: no information gives no stiffening).
/// @par Real-time  noexcept.
double stiffnessMultiplier(const CouplingParams& params, double rayLength) noexcept;

/// Everything one tick of the coupling computed (for the force, the proxy, traces and
/// snapshots).
struct CouplingOutput {
    Eigen::Vector3d force{Eigen::Vector3d::Zero()};  ///< F_pb on the user, N (before clamping)
    /// AVCEC's F_py = -1/2 D^2 grad_py k, in the tangent plane, N (zero otherwise): feed it to
    /// Proxy::update().
    Eigen::Vector3d proxyForce{Eigen::Vector3d::Zero()};
    /// AVCEC's spherical term -1/2 D (g1 e1 + g2 e2), N (already included in force).
    Eigen::Vector3d energyForce{Eigen::Vector3d::Zero()};
    double stiffness = 0;  ///< k used, N/m (low-passed, clamped)
    /// AVCEC: the stiffness that turns the proxy's tangential force into its step (k plus a
    /// bound on the tangential curvature of E's stiffness terms, from both stencils' second
    /// differences), N/m; k otherwise. See Proxy::update's stepStiffness.
    double stepStiffness = 0;
    double rayLength = 0;              ///< centre ray's L, m (L_max when nothing was found)
    double distance = 0;               ///< D, m
    double energy = 0;                 ///< 1/2 k D^2, J
    kernels::StencilGradient sphere;   ///< g1, g2, N/m per radian
    kernels::StencilGradient surface;  ///< along t1, t2, N/m per metre
    int rays = 0;                      ///< rays cast this tick
};

namespace detail {
struct RayAxis;  // where a tick's rays leave and along what (coupling.cpp)
}  // namespace detail

/// Computes the coupling force each tick. Holds the bundle and hit buffers, so a tick
/// allocates nothing.
///
/// What a tick computes (D = |x_pb - x_py|, d = (x_pb - x_py) / D, b = damping):
/// * VC (or a source without data): k = baseStiffness, F_pb = -k D d + b (v_py - v_pb); no ray,
///   rays = 0, rayLength = 0.
/// * AVC: the bundle from x_py along d; only the centre and ring rays are traced (bundle().count
///   is 1 + ringCount). Per ray k_r = min(k_s m(L_r), k_max) with L_r the mesh hit, the
///   first-hit t, or the accumulate stop t (L_max when nothing is found); k = lowPass(k_r)
///   (k_centre without a ring); F_pb = -k D d + b (v_py - v_pb).
/// * AVCEC: all rays. g = sphericalSobel(k_r), gs = surfaceSobel(k_r) on the raw per-ray k (the
///   stencil centre is the centre ray's unfiltered k, not the low-passed k);
///   energyForce = -1/2 D (g1 e1 + g2 e2) is added to F_pb; proxyForce = -1/2 D^2 (gs1 t1 +
///   gs2 t2) with e1, e2, t1, t2 from bundle(); on deformable tissue energyForce passes the
///   stiffness filter (CouplingParams::stiffnessTimeConstant). With a ring the low-passed k
///   and the raw-k gradient do not belong to one potential, so the closed-loop work is only ~0
///   without a ring (see test_coupling's energy test for the figures). With
///   CouplingParams::maxRayTilt below pi/2 (the default) the bundle leaves from the contact
///   plane's point above the probe along the limited axis, and energyForce is E's gradient
///   through that axis and origin (docs/algorithms.md section 3, "The rays' tilt").
/// * energy = 1/2 k D^2 in every mode; the damping force is not in energy.
///
/// @par Threading  One instance per servo loop; compute() from one thread at a time. The view
///      and scene must outlive it and must not change while compute() runs.
/// @par Real-time  compute() is noexcept, allocation-free, lock-free and bounded by the
///      bundle's ray count times kernels::kMaxSamplesPerRay.
class Coupling {
  public:
    /// @p volume is needed for the volume sources, @p hardMeshes for the mesh source (either
    /// may be null otherwise).
    /// @p movingMeshes (deformable scenes): a second scene of hard meshes that move (a
    /// deformable body's embedded meshes, refitted every tick) that the Mesh source also casts
    /// against with the same hardMask (per ray, the nearer hit of the two counts); with it the
    /// Mesh source has data even without static hard meshes.
    /// @throw palp::ValueError for invalid parameters, or (in AVC and AVCEC mode only) a source
    ///        without its data: a null view, or a null, empty or uncommitted mesh scene.
    Coupling(const kernels::VolumeView* volume, const kernels::EmbreeScene* hardMeshes,
             const CouplingParams& params, const kernels::EmbreeScene* movingMeshes = nullptr);

    /// Replaces the parameters (validate first with validateCouplingParams(); a source without
    /// its data falls back to VC and is reported through sourceAvailable()).
    void setParams(const CouplingParams& params) noexcept;
    const CouplingParams& params() const noexcept { return mParams; }
    /// Whether the current source has its data: a view for the volume sources, a non-empty
    /// committed scene for the mesh source (read each tick).
    bool sourceAvailable() const noexcept;

    /// One tick. @p tangent1, @p tangent2 span the surface stencil plane (the proxy's tangent
    /// frame; orthonormalised, and replaced by e1, e2 when degenerate). D < minDistance or
    /// any non-finite input (positions, velocities, tangents) gives a zero output, damping
    /// included. Positions in metres, velocities in m/s.
    void compute(const Eigen::Vector3d& proxy, const Eigen::Vector3d& probe,
                 const Eigen::Vector3d& proxyVelocity, const Eigen::Vector3d& probeVelocity,
                 const Eigen::Vector3d& tangent1, const Eigen::Vector3d& tangent2,
                 CouplingOutput& out) noexcept;

    /// The stored energy 1/2 k D^2 the coupling would have with the proxy at @p proxy and the
    /// probe at @p probe (k low-passed over the centre and ring rays, as compute() does, and
    /// through this tick's stiffness filter; only those rays are cast). 0 when D < minDistance or
    /// an input is not finite. Does not change bundle(). Used by the session to accept only AVCEC
    /// proxy moves that lower E.
    double storedEnergy(const Eigen::Vector3d& proxy, const Eigen::Vector3d& probe,
                        const Eigen::Vector3d& tangent1, const Eigen::Vector3d& tangent2) noexcept;

    /// Deformable scenes: the volume sources sample the scan where the tissue was at rest
    /// (docs/algorithms.md section 10). Each ray of the bundle (cast in the current, deformed
    /// configuration) is mapped to the rest configuration through @p body's displacement field
    /// (its origin and its far end by DeformableBody::restFromCurrent: the straight chord
    /// between them, exact for a uniform deformation along the ray), traced in the volume
    /// there, and its hit or stop point is mapped back (currentFromRest): L is the current
    /// distance from the proxy to where the structure is now. A structure that moves with the
    /// tissue (a tumour seen only in the scan) is then felt where it went, and a fixed one
    /// (bone) where it is. nullptr (default, rigid scenes): rays sample the volume where they
    /// are. Costs about 3 x 12 trilinear reads of the nodal displacements per ray (bounded).
    /// The Mesh source ignores it (its moving meshes are already deformed). @p body must
    /// outlive the coupling and be stepped on the same thread as compute().
    void setDeformation(const DeformableBody* body) noexcept { mDeformation = body; }

    /// Deformable scenes: the material frame at the contact, the rotation @p currentFromRest
    /// of the contacted surface element (DeformableBody::anchorRotation; identity: none, the
    /// default). The bundle is cast along R^T d with tangents R^T t1, R^T t2 instead of d, t1,
    /// t2: the proxy->probe direction as the tissue at the contact saw it at rest, so the
    /// slope of the dimple the proxy sits in does not turn the rays (on a pressed 5 kPa bone
    /// phantom it tilted them ~50 degrees). The AVCEC terms are rotated back by R: they stay
    /// the exact gradients of E = 1/2 k(R^T d) D^2 for the R of the tick. Set once per tick
    /// before compute()/storedEnergy(). @par Real-time
    void setMaterialFrame(const Eigen::Matrix3d& currentFromRest) noexcept {
        mFrame = currentFromRest;
        mFramed = !currentFromRest.isIdentity(0.0);
    }

    /// Starts a servo tick of period @p dtSeconds for the stiffness filter
    /// (CouplingParams::stiffnessTimeConstant): compute() and storedEnergy() until the next
    /// call filter from the k of the last compute() before it, so a tick that computes twice
    /// (an AVCEC move undone) advances the filter once. Never called (rigid scenes): k is
    /// unfiltered. A compute() without contact (D below minDistance, a non-finite input)
    /// restarts the filter from the next k_rays. @par Real-time
    void beginTick(double dtSeconds) noexcept;

    /// The last bundle cast (for viewers: the rays of this tick).
    const kernels::RayBundle& bundle() const noexcept { return mBundle; }

  private:
    /// The contact's inward unit normal for the rays' tilt limit: -(t1 x t2), or on a rigid
    /// volume scene the scan's own (its values' gradient at the proxy, continuous across the
    /// proxy mesh's facets), on the same side.
    Eigen::Vector3d inwardNormal(const Eigen::Vector3d& proxy, const Eigen::Vector3d& tangent1,
                                 const Eigen::Vector3d& tangent2) const noexcept;
    /// The rays' origin and axis for the proxy and the probe @p delta (D = |delta|) from it:
    /// AVCEC's tilt limit, or x_py along d, into @p axis; and the bundle cast from them into
    /// @p out. False when no rays are cast (VC, no source, a degenerate direction).
    bool castRays(const Eigen::Vector3d& proxy, const Eigen::Vector3d& delta, double D,
                  const Eigen::Vector3d& tangent1, const Eigen::Vector3d& tangent2,
                  detail::RayAxis& axis, kernels::RayBundle& out) noexcept;
    /// Traces the first @p n rays of @p bundle into per-ray stiffness @p k; the centre ray's
    /// length in @p centreLength.
    void traceStiffness(kernels::RayBundle& bundle, int n,
                        std::array<double, kernels::kMaxBundleRays>& k,
                        double& centreLength) noexcept;
    /// Deformable scenes: @p bundle's first @p n rays mapped to the rest configuration into
    /// mRestBundle; traceStiffness then maps the lengths back with restLength().
    const kernels::RayBundle& restBundle(const kernels::RayBundle& bundle, int n) noexcept;
    /// The current length of ray @p r whose rest trace stopped at rest distance @p tRest.
    double currentLength(const kernels::RayBundle& bundle, int r, double tRest) const noexcept;
    /// k_rays through the stiffness filter of this tick (beginTick); k_rays when it is off.
    double filtered(double kRays) const noexcept;

    const kernels::VolumeView* mVolume;
    const kernels::EmbreeScene* mMeshes;
    const kernels::EmbreeScene* mMoving = nullptr;
    const DeformableBody* mDeformation = nullptr;
    Eigen::Matrix3d mFrame = Eigen::Matrix3d::Identity();  // setMaterialFrame
    bool mFramed = false;                                  // mFrame is not the identity
    CouplingParams mParams;
    kernels::RayBundle mBundle;
    kernels::RayBundle mProbeBundle;  // storedEnergy()'s
    kernels::RayBundle mRestBundle;   // setDeformation: the rays in the rest configuration
    kernels::BundleHits mHits;
    kernels::BundleHits mMovingHits;
    kernels::BundleAccumulation mAccum;
    // The stiffness filter (beginTick): the k this tick filters from, its gain, and the last
    // compute()'s k (the next tick's start). Valid flags: a filter started and a k to start from.
    double mKStart = 0, mKGain = 1, mKLast = 0;
    bool mTicking = false, mKStartValid = false, mKLastValid = false;
    // AVCEC's spherical term through the same filter (zero after a tick without it).
    Eigen::Vector3d mEnergyForceStart = Eigen::Vector3d::Zero();
    Eigen::Vector3d mEnergyForceLast = Eigen::Vector3d::Zero();
};

}  // namespace palp::haptics
