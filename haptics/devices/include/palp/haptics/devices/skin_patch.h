#pragma once
/// @file
/// Where a scan's skin can be palpated from one side: the largest rectangle of a box face whose
/// skin faces the press axis, and the side of a box with the most such skin. The defaults of
/// `palp palpate` on a scan, so that a simulated hand laid on the skin (skin_field.h) stays on
/// it.

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <array>
#include <span>

namespace palp::kernels {
class EmbreeScene;
}  // namespace palp::kernels

namespace palp::haptics {

/// A signed coordinate axis.
enum class SignedAxis { PlusX, MinusX, PlusY, MinusY, PlusZ, MinusZ };
/// The unit vector of @p axis.
Eigen::Vector3d axisVector(SignedAxis axis) noexcept;

/// A rectangle on the plane of a box face, its press axis into the box, and its skin.
struct SkinPatch {
    Eigen::Vector3d centre{Eigen::Vector3d::Zero()};  ///< on the face's plane, m
    Eigen::Vector3d u{Eigen::Vector3d::UnitX()};      ///< unit, lateral (the smaller axis index)
    Eigen::Vector3d v{Eigen::Vector3d::UnitZ()};      ///< unit, lateral (the larger axis index)
    Eigen::Vector3d press{Eigen::Vector3d::UnitY()};  ///< unit axis, into the box
    double extentU = 0, extentV = 0;                  ///< m (0, 0: no skin faces the axis)
    /// Share of the whole face whose skin faces the axis (before the rectangle is taken).
    double facingFraction = 0;
};

/// How findSkinPatch() judges the skin.
struct SkinPatchOptions {
    double cellM = 2e-3;    ///< grid of the rays over the face, m
    double smoothM = 2e-3;  ///< Gaussian smoothing of the heights before the slope, m
    double maxSlope = 0.7;  ///< skin "faces" the axis where |grad h| <= this (35 degrees)
    double marginM = 5e-3;  ///< the rectangle is shrunk by this on every side, m
};

/// The largest axis-aligned rectangle of the face of @p box against @p press (a unit axis:
/// +-x, +-y, +-z; the face where the press enters the box) on which rays along @p press hit the
/// skin (@p surfaces, mask kMaskSurface) with a slope of at most options.maxSlope at every grid
/// node, less options.marginM per side. extentU = extentV = 0 when there is none.
/// @throw palp::ValueError for an empty box, a press that is not an axis, bad options.
SkinPatch findSkinPatch(const kernels::EmbreeScene& surfaces, const Eigen::AlignedBox3d& box,
                        const Eigen::Vector3d& press, const SkinPatchOptions& options = {});

/// The press axes findBestSkinPatch() tries by default, in order of preference: +y, -y, +x, -x,
/// +z, -z (in LPS, into the body from the anterior, posterior, right, left, inferior and
/// superior faces).
inline constexpr std::array<SignedAxis, 6> kAllPressAxes = {SignedAxis::PlusY, SignedAxis::MinusY,
                                                            SignedAxis::PlusX, SignedAxis::MinusX,
                                                            SignedAxis::PlusZ, SignedAxis::MinusZ};
/// The four sides across the patient's long axis (S/I): the ends of an axial scan along S/I are
/// where the scan cuts through the body (flat faces of tissue, not skin).
inline constexpr std::array<SignedAxis, 4> kSidePressAxes = {SignedAxis::PlusY, SignedAxis::MinusY,
                                                             SignedAxis::PlusX, SignedAxis::MinusX};

/// findSkinPatch() on the faces of @p box against each of @p axes; the one with the largest
/// rectangle (area), ties to the earlier in @p axes.
SkinPatch findBestSkinPatch(const kernels::EmbreeScene& surfaces, const Eigen::AlignedBox3d& box,
                            const SkinPatchOptions& options = {},
                            std::span<const SignedAxis> axes = kAllPressAxes);

}  // namespace palp::haptics
