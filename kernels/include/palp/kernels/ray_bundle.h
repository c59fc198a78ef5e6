#pragma once
/// @file
/// AVC/AVCEC ray bundles (ALGORITHMS.md sections 2 and 3): the centre ray, a low-pass ring, the
/// spherical 3x3 Sobel stencil ("blue rays") and the surface 3x3 Sobel stencil ("green rays"),
/// stored as structure-of-arrays in fixed-capacity buffers; and the Sobel gradient functions.

#include <Eigen/Core>
#include <array>
#include <cstdint>
#include <span>

namespace palp::kernels {

/// Most rays a bundle holds: 1 centre + ring + 8 spherical + 8 surface.
inline constexpr int kMaxBundleRays = 64;
/// Rays of a bundle without ring: centre + 8 spherical + 8 surface.
inline constexpr int kBundleRaysWithoutRing = 17;
/// Largest ring a bundle can hold.
inline constexpr int kMaxRingRays = kMaxBundleRays - kBundleRaysWithoutRing;

/// Shape of a bundle. Set up once; validate with validateBundleParams() at set-up.
struct BundleParams {
    double length = 10e-3;          ///< L_max, metres: every ray of the bundle has this length
    int ringCount = 0;              ///< n, number of ring rays (0..kMaxRingRays)
    double ringHalfAngle = 0.1;     ///< alpha, radians: half-angle of the ring cone around d
    double ringWeightSigma = 0.1;   ///< radians: Gaussian width; ring weight exp(-alpha^2/(2 s^2))
    double sobelAngle = 0.05;       ///< delta, radians: spacing of the spherical Sobel stencil
    double surfaceOffset = 0.5e-3;  ///< h, metres: spacing of the surface Sobel stencil
};

/// Throws palp::ValueError naming the field when @p params is unusable (non-finite or
/// non-positive length, ringCount outside 0..kMaxRingRays, angles outside (0, pi/2), ...).
/// @par Threading  Any thread.
void validateBundleParams(const BundleParams& params);

/// A bundle of rays as structure-of-arrays (all world metres, LPS). Directions are unit vectors.
/// Ray order: [0] centre, [1, 1 + ringCount) ring, then 8 spherical Sobel rays, then 8 surface
/// Sobel rays. Stencil rays are stored in row order (j = -1, 0, 1; i = -1, 0, 1) skipping the
/// centre (i = j = 0), which is the centre ray itself.
///
/// @par Threading  A plain value: one writer, or many readers.
/// @par Real-time  Fixed capacity, no heap memory; safe to keep on the servo thread's stack.
struct RayBundle {
    std::array<float, kMaxBundleRays> ox{}, oy{}, oz{};  ///< origins, metres
    std::array<float, kMaxBundleRays> dx{}, dy{}, dz{};  ///< unit directions
    std::array<float, kMaxBundleRays> length{};          ///< ray lengths, metres
    std::array<float, kMaxBundleRays>
        weight{};              ///< low-pass weights (centre and ring, sum 1), 0 for stencils
    int count = 0;             ///< rays in use; 0 for an invalid bundle
    int ringBegin = 1;         ///< index of the first ring ray
    int ringCount = 0;         ///< number of ring rays
    int sphereBegin = 1;       ///< index of the first of the 8 spherical Sobel rays
    int surfaceBegin = 9;      ///< index of the first of the 8 surface Sobel rays
    bool valid = false;        ///< false when the direction or origin was degenerate
    double sobelAngle = 0;     ///< delta used, radians
    double surfaceOffset = 0;  ///< h used, metres
    Eigen::Vector3d origin = Eigen::Vector3d::Zero();      ///< x_py
    Eigen::Vector3d direction = Eigen::Vector3d::UnitZ();  ///< d
    Eigen::Vector3d e1 =
        Eigen::Vector3d::UnitX();  ///< spherical stencil axis i (perpendicular to d)
    Eigen::Vector3d e2 =
        Eigen::Vector3d::UnitY();  ///< spherical stencil axis j (perpendicular to d, e1)
    Eigen::Vector3d t1 = Eigen::Vector3d::UnitX();  ///< surface stencil axis i (tangent)
    Eigen::Vector3d t2 = Eigen::Vector3d::UnitY();  ///< surface stencil axis j (tangent)

    /// Index of stencil entry (i, j), i, j in {-1, 0, 1}, among the spherical rays (0 -> centre).
    int sphereRay(int i, int j) const noexcept { return stencilRay(sphereBegin, i, j); }
    /// Index of stencil entry (i, j) among the surface rays (0, 0 -> centre).
    int surfaceRay(int i, int j) const noexcept { return stencilRay(surfaceBegin, i, j); }

  private:
    static int stencilRay(int begin, int i, int j) noexcept {
        const int s = (j + 1) * 3 + (i + 1);
        if (s == 4) return 0;
        return begin + (s < 4 ? s : s - 1);
    }
};

/// A unit vector pair (e1, e2) perpendicular to unit @p d, continuous almost everywhere and
/// deterministic (Duff et al. 2017 construction).
/// @par Real-time  noexcept, no allocation.
void orthonormalBasis(const Eigen::Vector3d& d, Eigen::Vector3d& e1, Eigen::Vector3d& e2) noexcept;

/// Fills @p out with the bundle cast from the proxy @p origin (metres) towards @p direction
/// (any non-zero length; normalised here). @p tangent1 and @p tangent2 span the surface stencil
/// plane (the tangent plane at the proxy); they are orthonormalised here, and replaced by e1, e2
/// when degenerate. Spherical rays point along normalize(d + tan(i delta) e1 + tan(j delta) e2);
/// surface rays start at origin + h (i t1 + j t2) with direction d; ring rays lie on the cone of
/// half-angle alpha at azimuths 2 pi m / n. Weights: centre 1, ring exp(-alpha^2 / (2 s^2)),
/// normalised to sum 1.
/// A zero, NaN or infinite direction or origin gives `valid = false`, `count = 0`.
/// @return out.valid
/// @par Threading  Pure; any thread.
/// @par Real-time  noexcept, no allocation, bounded (at most kMaxBundleRays rays).
bool generateBundle(const Eigen::Vector3d& origin, const Eigen::Vector3d& direction,
                    const Eigen::Vector3d& tangent1, const Eigen::Vector3d& tangent2,
                    const BundleParams& params, RayBundle& out) noexcept;

/// Two derivatives from a 3x3 stencil.
struct StencilGradient {
    double g1 = 0;  ///< derivative along axis i (e1 or t1), per radian or per metre
    double g2 = 0;  ///< derivative along axis j (e2 or t2)
};

/// 3x3 Sobel: g1 = sum Sx(i,j) k(i,j) / (8 spacing), g2 = sum Sy(i,j) k(i,j) / (8 spacing), with
/// Sx = [[-1,0,1],[-2,0,2],[-1,0,1]] (rows j, columns i) and Sy = Sx^T.
/// @param k  values at (i, j), stored k[(j + 1) * 3 + (i + 1)]
/// @param spacing  stencil spacing (delta in radians, or h in metres); must be > 0
/// @par Real-time  noexcept, no allocation.
StencilGradient sobel3x3(const std::array<double, 9>& k, double spacing) noexcept;

/// Gathers the spherical stencil's 3x3 values from per-ray values (shape: bundle.count) and
/// applies sobel3x3 with spacing bundle.sobelAngle: the angular derivatives g1, g2 of AVCEC
/// (per radian). Returns zeros for an invalid bundle or a too short span.
/// @par Real-time  noexcept, no allocation.
StencilGradient sphericalSobel(const RayBundle& bundle, std::span<const double> perRay) noexcept;

/// Same for the surface stencil, spacing bundle.surfaceOffset: derivatives along t1, t2 (per
/// metre).
/// @par Real-time  noexcept, no allocation.
StencilGradient surfaceSobel(const RayBundle& bundle, std::span<const double> perRay) noexcept;

/// Low-pass filtered value: sum over centre and ring of weight * perRay.
/// @par Real-time  noexcept, no allocation.
double lowPass(const RayBundle& bundle, std::span<const double> perRay) noexcept;

}  // namespace palp::kernels
