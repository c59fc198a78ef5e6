#pragma once
/// @file
/// The skin under a path: a height field over a rectangle of a plane, measured along a press
/// axis with the scene's own surface rays at set-up, smoothed and slope-limited, so that a
/// scripted path (trajectory.h) can be laid on the skin and sampled on the servo thread without
/// a ray or an allocation.
///
/// Frame: the plane through @p centre spanned by unit @p u and @p v (perpendicular), the press
/// axis @p press (unit, into the body; not necessarily perpendicular to the plane, the field
/// measures along it). A point p has lateral coordinates a = (p - centre) . u,
/// b = (p - centre) . v; the skin under it lies at p + h(a, b) press, h in metres from the
/// plane (h > 0: the skin is deeper than the plane along press).

#include <Eigen/Core>
#include <vector>

namespace palp::kernels {
class EmbreeScene;
}  // namespace palp::kernels

namespace palp::haptics {

/// Where and how finely to measure the skin.
struct SkinFieldSpec {
    Eigen::Vector3d centre{Eigen::Vector3d::Zero()};  ///< on the plane, m
    Eigen::Vector3d u{Eigen::Vector3d::UnitX()};      ///< unit, lateral
    Eigen::Vector3d v{Eigen::Vector3d::UnitZ()};      ///< unit, lateral, perpendicular to u
    Eigen::Vector3d press{Eigen::Vector3d::UnitY()};  ///< unit, into the body
    double extentU = 0.06, extentV = 0.06;            ///< size of the rectangle, m
    /// Grid cell edge, m: the resolution of the path's depth (about the raster spacing).
    double cellM = 1e-3;
    /// Rays start this far outside the plane (against press), m, so skin that bulges beyond the
    /// plane is found.
    double startOffsetM = 0.01;
    /// Rays are this long from their start, m (no hit within: no skin under that cell).
    double rayLengthM = 0.3;
    /// Gaussian smoothing of the heights, sigma in m (0: none).
    double smoothM = 2e-3;
    /// Largest |dh/ds| along the plane after limiting: where the skin rises faster toward the
    /// hand than this (a nose, an ear), the path rises earlier, over a slope of this size, so
    /// it never cuts into the skin more steeply than the press depth allows.
    double maxSlope = 1.0;
};

/// @throw palp::ValueError naming the field (non-finite, non-positive sizes, axes not unit or
///        not perpendicular, more than 4096 cells along a side).
void validateSkinFieldSpec(const SkinFieldSpec& spec);

/// A skin height field (see the file comment).
/// @par Threading  Built on one thread; then immutable and safe to read from any number.
class SkinField {
  public:
    /// A flat skin on the plane itself (h = 0 everywhere).
    SkinField() = default;

    /// Casts one ray per grid node along spec.press against @p surfaces (the proxy's surfaces,
    /// mask kMaskSurface: the same Embree scene the session's proxy slides on), fills nodes
    /// without a hit from their neighbours, smooths and limits the slope.
    /// @throw palp::ValueError from validateSkinFieldSpec(), or when no ray finds the skin
    ///        (naming the plane and the press axis).
    static SkinField measure(const kernels::EmbreeScene& surfaces, const SkinFieldSpec& spec);

    const SkinFieldSpec& spec() const noexcept { return mSpec; }
    int nodesU() const noexcept { return mNu; }
    int nodesV() const noexcept { return mNv; }
    /// Lateral coordinates (m) of node (i, j).
    double nodeA(int i) const noexcept;
    double nodeB(int j) const noexcept;
    /// Smoothed, slope-limited height at node (i, j), m (what paths follow).
    double height(int i, int j) const noexcept;
    /// Height measured by the ray at node (i, j), m; NaN where the ray found no skin.
    double rawHeight(int i, int j) const noexcept;
    /// Share of nodes whose ray found the skin.
    double hitFraction() const noexcept;
    /// World point of the measured skin at node (i, j) (NaN where none).
    Eigen::Vector3d skinPoint(int i, int j) const noexcept;

    /// Height h (m) and its gradient (dh/da, dh/db) at lateral (@p a, @p b): bilinear between
    /// nodes, clamped to the rectangle's edge outside it (0 for a default-made field).
    /// @par Real-time  noexcept, no allocation.
    void sample(double a, double b, double& h, double& dhda, double& dhdb) const noexcept;

    /// Lays a point of a flat path on the skin: @p position moves by h press at its lateral
    /// coordinates and @p velocity gains the rate of h along the path, (dh/da a' + dh/db b')
    /// press, so the velocity stays the derivative of the position.
    /// @par Real-time  noexcept, no allocation.
    void apply(Eigen::Vector3d& position, Eigen::Vector3d& velocity) const noexcept;

  private:
    SkinFieldSpec mSpec;
    int mNu = 0, mNv = 0;
    std::vector<double> mHeight;  // smoothed, limited; row-major in v
    std::vector<double> mRaw;     // as measured, NaN for no hit
};

}  // namespace palp::haptics
