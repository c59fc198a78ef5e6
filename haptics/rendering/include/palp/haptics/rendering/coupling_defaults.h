#pragma once
/// @file
/// Coupling defaults of the thesis scenes and of scans (docs/algorithms.md sections 2, 3 and 9).
/// Used by `palp palpate`, `palp bench` and the virtual experiments (test_experiments).

#include "palp/haptics/rendering/coupling.h"
#include "palp/volume/phantom.h"

namespace palp::haptics {

/// Coupling defaults for a thesis scene (mode AVC or AVCEC, ray source, lengths, stiffness).
///
/// * Avc: the rigid plate (y 10-12 mm) hides the box (y 20-28 mm) from a first-hit ray, so the
///   source is VolumeAccumulate with sigma = 1/mm above 500 HU (a step between soft 40 HU and
///   rigid 1000 HU) and tau_stop = 3: the 2 mm plate alone (tau = 2) does not stop the ray, the
///   plate plus 1 mm of box does, so L ~ 21 mm over the box and L_max = 40 mm elsewhere (the
///   block is 50 mm deep, nothing rigid below the box). L_ref = L_max = 40 mm, so m(L_max) = 1
///   (soft tissue feels like k_s) and m(21 mm) ~ 1.9: the box nearly doubles k (a change of
///   about 90 %, six times the 15.8 % lateral-sweep stiffness JND of section 8).
/// * Avcec: the plate (y 8-10 mm) is not obscured: VolumeFirstHit at 500 HU, L_max = 40 mm,
///   L_ref = 20 mm, so k = k_s over soft tissue and 2.5 k_s over the plate (L ~ 8 mm).
/// * Bone: VolumeFirstHit at 500 HU, L_max = 40 mm, L_ref = 40 mm (slab top 25 mm +- 7 mm).
/// * Stiffness: the boxes' stiffness field, not a surface of it: VolumeAccumulate, tau_stop 3,
///   sigma(v) piecewise linear in the value (15 nodes), zero halfway between fat (-100 HU) and
///   soft tissue (40 HU), then chosen so that a column of value v under the 2 mm fat layer stops
///   the ray at L(v) = L_ref / m(v) with m(v) linear from 1.25 (soft, 40 HU) to 3.25 (hard,
///   300 HU): k is linear in the value, 375-975 N/m at k_s 300, and a sweep across the CL box
///   feels its linear, cosine or tanh profile (a first-hit threshold at 200 HU made all three
///   one step). L_max = L_ref = 40 mm. Friction tilts the rays ahead of the hand in a sweep
///   (they run from proxy to probe), so the field is read where the finger is only without it
///   (`palp study` stimuli are frictionless by default).
/// Common: k_s = 300 N/m, m_max = 8, k_max = 2400 N/m (clamp to the device with
/// limitStiffnessToDevice()), step 0.5 mm (1 mm voxels and finer), no ring (ringCount 0), Sobel
/// angle 0.1 rad and surface offset 1 mm (the stencils must straddle structures a few mm wide).
CouplingParams sceneCouplingDefaults(volume::PhantomScene scene);

/// Coupling defaults for a scan (CT assumed): AVC, VolumeFirstHit at 300 HU (bone), L_max =
/// L_ref = 40 mm (k_s when nothing hard lies within 40 mm, 4 k_s for bone 10 mm deep),
/// otherwise as sceneCouplingDefaults().
CouplingParams scanCouplingDefaults();

}  // namespace palp::haptics
