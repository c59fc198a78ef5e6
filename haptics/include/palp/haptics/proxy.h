#pragma once
/// @file
/// The proxy (god-object, Zilles-Salisbury) on Embree surfaces with Coulomb friction
/// (ALGORITHMS.md section 1): the proxy follows the probe in free space, stops on the first
/// surface the segment proxy -> probe hits, and in contact stays on up to three constraint
/// planes (faces, edges, corners), sticking or slipping on the friction cone.

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
    /// Orthonormal tangent frame at the contact (t1, t2 perpendicular to the first normal);
    /// arbitrary but continuous in free space. Used for the surface Sobel stencil.
    Eigen::Vector3d tangent1{Eigen::Vector3d::UnitX()};
    Eigen::Vector3d tangent2{Eigen::Vector3d::UnitZ()};
    bool sticking = false;  ///< in contact and inside the static friction cone
};

/// God-object proxy against an EmbreeScene.
///
/// @par Threading  One instance per servo loop; update() from the servo thread only. The scene
///      must be committed and not modified while update() runs.
/// @par Real-time  update() and reset() are noexcept, allocation-free and bounded
///      (at most maxIterations + 1 closest-hit queries of a few rays each).
class Proxy {
  public:
    /// @p scene must outlive the proxy. An empty scene is allowed (the proxy then equals the
    /// probe).
    Proxy(const kernels::EmbreeScene& scene, const ProxyParams& params);

    /// Puts the proxy at @p position with no contact (e.g. at start: the probe position).
    void reset(const Eigen::Vector3d& position) noexcept;

    /// One tick. @p probe is x_pb (m). @p tangentialForce is an extra force on the proxy in the
    /// tangent plane (AVCEC's F_py, N), added to the coupling's pull k (x_pb - x_py) in the
    /// friction test; @p stiffness is k (N/m, > 0), used to turn forces into displacements.
    /// @p dt is the tick period (s) for the velocity estimate.
    /// Non-finite input leaves the proxy where it was.
    const ProxyState& update(const Eigen::Vector3d& probe, const Eigen::Vector3d& tangentialForce,
                             double stiffness, double dt) noexcept;

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
