#pragma once
/// @file
/// The triangle mesh the Embree scene and the refit BVH take (palp::TriangleMesh, defined in
/// base so that volume's mesh I/O and iso-surfaces can produce it without the kernels).

#include "palp/base/triangle_mesh.h"

namespace palp::kernels {

using palp::TriangleMesh;

}  // namespace palp::kernels
