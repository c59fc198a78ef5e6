#pragma once
/// @file
/// The proxy (god-object, Zilles-Salisbury) on Embree surfaces with Coulomb friction
/// (docs/algorithms.md section 1): the proxy follows the probe in free space, stops on the first
/// surface the segment proxy -> probe hits, and in contact stays on up to three constraint
/// planes (faces, edges, corners), sticking or slipping on the friction cone.
///
/// One update() (all in double precision except Embree's ray test):
/// 1. Trace the segment x_py -> x_pb (extended by epsilon, so that a probe just short of a
///    surface counts as touching it). No hit: the proxy moves to the probe (free motion).
/// 2. A hit gives the constraint plane of the hit triangle, computed from its vertices, with the
///    normal n = -sign(Ng.u) Ng/|Ng| facing the side the segment came from (meshes need no
///    consistent winding) and offset epsilon: n.x = n.v0 + epsilon. The proxy advances along the
///    hit-free segment to that offset plane, or stays where it is when already on it (within
///    1e-3 epsilon) or below it.
/// 3. Coulomb friction on this first plane: f = k (x_pb - x_py) + F_t, where F_t is
///    tangentialForce with its component along n removed. f_n = -f.n (pressing), f_t the rest.
///    |f_t| <= mu_s f_n: the proxy sticks (no motion, sticking = true). Otherwise it slides by
///    (|f_t| - mu_d f_n) / k along f_t, which never passes the goal x + f_t / k (the projection
///    of the probe onto the plane, shifted by F_t / k); with mu = 0 it reaches the goal. With a
///    step stiffness above k (AVCEC) the F_t share of the slide is damped (update()).
/// 4. Each further motion segment is traced again; a new hit advances to its offset plane and
///    adds it (at most three). The goal is then the point closest to the step-3 target in the
///    intersection of the half-spaces n_i.x >= d_i, i.e. a projection onto 1 plane, the line of
///    2 or the point of 3, chosen so that no plane is violated (planes the target is above are
///    released). Normal forces of the second and third plane do not enter the friction test.
/// 5. Embree's ray test is not watertight (a ray through a shared edge can slip between two
///    triangles, in both directions), so every move is confirmed by a reverse ray on a line
///    shifted sideways by 0.05 epsilon; a surface it meets blocks the move like a forward hit.
/// 6. At most maxIterations + 1 segments are traced (two rays each). When they run out, or a
///    fourth plane or a degenerate one (grazing, parallel) is met, the proxy stays at the last
///    position it reached along confirmed segments. It therefore never crosses a surface of
///    surfaceMask it did not start inside, up to single-precision ray tests: a proxy that free
///    motion leaves within float rounding (about 1e-9 m at centimetre coordinates) of a
///    surface has no reliable side, and may then stick to it or slip through it.
/// 7. A proxy that started in contact keeps its state (sticking) when the move would raise its
///    potential 1/2 k |x_pb - x|^2 - F_t . (x - x_start). Steps 3 and 4 lower it; a path
///    through more facets than three planes hold can raise it: in a pit of four or more
///    facets each triple of offset planes meets at its own point, and a held proxy hopped
///    between them every tick (the bottom of a pressed dimple on deformable tissue).
///
/// Constraint planes are found again every tick (only the position and whether the proxy is in
/// contact are carried over: reset() clears the contact, carry() keeps it), so
/// moving or deforming surfaces and faceted curved surfaces need no special handling, and a
/// proxy that slides past a convex edge leaves the face's plane when the probe is not under
/// it. Active planes reported in ProxyState are those whose clearance shell holds the proxy
/// (on the offset plane within 1e-3 epsilon, or between it and the surface) and the probe is
/// below; normals[0] is the friction plane. The shell matters on faceted surfaces: past a
/// concave facet junction (on a noisy scan's iso-surface, nearly every one) a proxy that slid
/// on one facet's offset plane is closer than epsilon to the next facet, and while it sticks
/// it stays there, held by that facet. Against a convex object one plane is active (two only
/// on the line where two offset planes meet, rare); two and three are the rule in concave
/// edges and corners.

#include <Eigen/Core>
#include <array>

#include "palp/kernels/embree_scene.h"

namespace palp::haptics {

/// Proxy settings. Validate with validateProxyParams() at set-up.
struct ProxyParams {
    double staticFriction = 0.5;   ///< mu_s: stick while |f_t| <= mu_s |f_n|
    double dynamicFriction = 0.3;  ///< mu_d (<= mu_s): slipping leaves |f_t| = mu_d |f_n|
    double epsilon = 1e-5;         ///< m: distance the proxy keeps from a surface
    unsigned surfaceMask = kernels::kMaskSurface;  ///< geometries the proxy cannot cross
    int maxIterations = 4;  ///< constraint-plane passes per update (bounded work)
};

/// @throw palp::ValueError naming the field (negative or non-finite friction, mu_d > mu_s,
///        non-positive epsilon, maxIterations outside 1..16).
void validateProxyParams(const ProxyParams& params);

/// Proxy state after an update.
struct ProxyState {
    Eigen::Vector3d position{Eigen::Vector3d::Zero()};  ///< x_py, m
    Eigen::Vector3d velocity{Eigen::Vector3d::Zero()};  ///< v_py, m/s (finite difference)
    int contactCount = 0;                               ///< active constraint planes, 0..3
    std::array<Eigen::Vector3d, 3> normals{};  ///< unit outward normals of the active planes
    /// Orthonormal tangent frame at the contact (t1, t2 perpendicular to the first normal,
    /// t2 = n x t1); t1 is the previous t1 with its normal part removed, so the frame turns
    /// continuously; in free space the last frame is kept. Used for the surface Sobel stencil.
    Eigen::Vector3d tangent1{Eigen::Vector3d::UnitX()};
    Eigen::Vector3d tangent2{Eigen::Vector3d::UnitZ()};
    bool sticking = false;  ///< in contact and inside the static friction cone
    int queries = 0;        ///< rays traced by the last update(), <= 2 (maxIterations + 1)
};

/// God-object proxy against an EmbreeScene.
///
/// @par Threading  One instance per servo loop; update() from the servo thread only. The scene
///      must be committed and not modified while update() runs.
/// @par Real-time  update() and reset() are noexcept, allocation-free and bounded
///      (at most 2 (maxIterations + 1) closest-hit rays).
class Proxy {
  public:
    /// @p scene must outlive the proxy. An empty scene is allowed (the proxy then equals the
    /// probe).
    Proxy(const kernels::EmbreeScene& scene, const ProxyParams& params);

    /// Puts the proxy at @p position with no contact (e.g. at start: the probe position).
    void reset(const Eigen::Vector3d& position) noexcept;

    /// Moves the proxy to @p position with the surface it is in contact with (a deformable
    /// surface that carried it), keeping its contact (planes, normals, tangents, sticking); the
    /// velocity becomes zero, as reset() does. The next update() finds its planes again.
    void carry(const Eigen::Vector3d& position) noexcept;

    /// Puts back a state this proxy had (e.g. state() before an update() whose move the caller
    /// rejects); the velocity becomes zero (the proxy did not move).
    void restore(const ProxyState& state) noexcept;

    /// One tick. @p probe is x_pb (m). @p tangentialForce is an extra force on the proxy in the
    /// tangent plane (AVCEC's terms, N), added to the coupling's pull k (x_pb - x_py) in the
    /// friction test; @p stiffness is k (N/m, > 0), the spring of the friction test.
    /// @p stepStiffness (N/m; ignored unless > stiffness) damps the slide, a
    /// Levenberg-Marquardt step where the extra force varies quickly with position (AVCEC's
    /// stiffness gradients), and @p springStepStiffness (N/m, clamped to [stiffness,
    /// stepStiffness]; 0: stepStiffness) damps the spring's share of it: friction leaves the
    /// fraction s = (|f_t| - mu_d f_n) / |f_t| of the tangential force and, with
    /// a = f_spring,t / stiffness (the way to the probe's projection), the proxy slides by
    /// s ((stiffness a + F_t) / stepStiffness + (stiffness / springStepStiffness - stiffness /
    /// stepStiffness) r a). With springStepStiffness = stiffness the spring's pull moves the
    /// proxy as in plain AVC and only F_t is damped. r = 1 unless F_t opposes a; then r a ends
    /// where the two balance along a (r = 0 when F_t wins), so the step lowers the potential
    /// (step 7 of the file's description).
    /// @p dt is the tick period (s) for the velocity estimate.
    /// Non-finite input, or a non-positive stiffness or dt, leaves the whole state unchanged.
    /// An empty or uncommitted scene: the proxy equals the probe.
    const ProxyState& update(const Eigen::Vector3d& probe, const Eigen::Vector3d& tangentialForce,
                             double stiffness, double dt, double stepStiffness = 0,
                             double springStepStiffness = 0) noexcept;

    const ProxyState& state() const noexcept { return mState; }
    /// Changes the parameters (validated by the caller); takes effect at the next update().
    void setParams(const ProxyParams& params) noexcept { mParams = params; }
    const ProxyParams& params() const noexcept { return mParams; }

  private:
    const kernels::EmbreeScene* mScene;
    ProxyParams mParams;
    ProxyState mState;
};

}  // namespace palp::haptics
