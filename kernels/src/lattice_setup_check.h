#pragma once
/// @file
/// Internal to the ray kernels, for the tests (tests/kernels reach kernels/src privately): the
/// check of the HitField path's vectorised ray set-up against its scalar set-up.

#include "palp/kernels/ray_bundle.h"
#include "palp/kernels/volume_ray.h"

namespace palp::kernels::detail {

/// What checkLatticeSetup() found.
struct LatticeSetupCheck {
    bool available = false;  ///< AVX2 present and @p params' field used for this view
    int vectorRays = 0;      ///< rays the vector set-up took (the rest go to the scalar one)
    int mismatches = 0;      ///< of those, rays whose set-up differs in any bit
};

/// The HitField path's vectorised ray set-up (four rays per AVX2 step) against its scalar
/// set-up on every ray of @p bundle that the vector set-up takes (first_hit.cpp).
LatticeSetupCheck checkLatticeSetup(const VolumeView& view, const RayBundle& bundle,
                                    const FirstHitParams& params) noexcept;

}  // namespace palp::kernels::detail
