#pragma once
/// @file
/// Projections of a scan along the press axis over a map's pixels, drawn in grey under the map
/// (MapUnderlay) so that what the hand felt can be compared with the anatomy: the depth of the
/// skin below the map's plane, and the maximum of the volume along the press (MIP). Computed off
/// the servo thread (before or after a run).

#include <Eigen/Core>

#include "palp/studies/scalar_map.h"
#include "palp/volume/volume.h"

namespace palp::kernels {
class EmbreeScene;
}  // namespace palp::kernels

namespace palp::haptics {

/// The skin depth under each pixel of @p plane: the distance (mm) along @p press (unit, into the
/// body) from the plane (through plane.centre) to the first surface of @p surfaces (mask
/// kMaskSurface: the skin the proxy slides on) hit by a ray from the pixel's centre, within
/// @p lengthM; NaN where none is. Negative where the skin bulges out of the plane (rays start
/// 10 mm before it).
/// @throw palp::ValueError for a press not unit or not perpendicular to the plane, or a
///        non-positive length.
ScalarMap skinDepthMap(const kernels::EmbreeScene& surfaces, const MapPlane& plane,
                       const Eigen::Vector3d& press, double lengthM);

/// The maximum of @p vol (its units, HU for CT; trilinear samples one voxel apart) along
/// @p press from each pixel's centre on @p plane over @p lengthM; NaN where every sample lies
/// outside the volume's active voxels' box. With @p fromMm (a map over the same plane and
/// pixels, e.g. skinDepthMap()), each pixel's slab starts that far (mm) along the press instead
/// (a slab under the skin); pixels where it is NaN stay NaN.
/// @throw palp::ValueError as skinDepthMap(), or for a @p fromMm over other pixels.
ScalarMap mipMap(const volume::Volume& vol, const MapPlane& plane, const Eigen::Vector3d& press,
                 double lengthM, const ScalarMap* fromMm = nullptr);

}  // namespace palp::haptics
