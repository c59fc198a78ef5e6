#pragma once
// The TLED tests' shared set-ups: the soft cube (10 mm, E 10 kPa, nu 0.45) compressed
// between rollers or bonded plates, and a quasi-static run of the explicit solver to rest.

#include <algorithm>
#include <vector>

#include "palp/fem/constraints.h"
#include "palp/fem/explicit_solver.h"
#include "palp/fem/hex_mesh.h"

namespace palp::fem::test {

inline constexpr double kTledE = 1.0e4, kTledNu = 0.45;

/// The neo-Hookean tissue of the tests: E 10 kPa, nu 0.45, rho 1000 kg/m^3, mass damping
/// @p alpha 1/s.
inline ElasticMaterial neoHookeanTissue(double alpha = 0.0) {
    ElasticMaterial m;
    m.youngsModulus = kTledE;
    m.poissonRatio = kTledNu;
    m.density = 1.0e3;
    m.dampingAlpha = alpha;
    m.law = MaterialLaw::neoHookean;
    return m;
}

/// The 10 mm cube of @p cells^3 elements.
inline HexMesh tledCube(int cells = 4) {
    return HexMesh::box(Eigen::Vector3d::Constant(0.01), {cells + 1, cells + 1, cells + 1}, kTledE);
}

/// How the cube is held: on rollers (x = 0, y = 0 and z = 0 faces slide, the top slides
/// down: homogeneous uniaxial stress) or bonded between clamped plates (bottom fixed, top
/// moved down without sliding: the cube bulges).
enum class Plates { rollers, bonded };

/// Supports of @p plates on @p mesh; the top face's z dofs are constrained (driven) in both.
inline Constraints plateConstraints(const HexMesh& mesh, Plates plates) {
    Constraints c(mesh.dofCount());
    if (plates == Plates::rollers) {
        c.fixNodes(mesh.faceNodes(BoxFace::xMin), 1u);
        c.fixNodes(mesh.faceNodes(BoxFace::yMin), 2u);
        c.fixNodes(mesh.faceNodes(BoxFace::zMin), 4u);
        c.fixNodes(mesh.faceNodes(BoxFace::zMax), 4u);
    } else {
        c.fixNodes(mesh.faceNodes(BoxFace::zMin));
        c.fixNodes(mesh.faceNodes(BoxFace::zMax));
    }
    return c;
}

/// Drives the top face of @p model down by @p strain of its 10 mm height over 50 ms ticks of
/// 1 ms and holds it 250 ms more (the model's mass damping brings it to rest): the top face's
/// reaction, N (positive in compression). @p last gets the last step's result.
inline double settledTopReaction(const FemModel& model, const Constraints& c, double strain,
                                 TledIntegration integration, StepResult* last = nullptr) {
    const std::vector<int> top = model.mesh().faceNodes(BoxFace::zMax);
    ExplicitOptions o;
    o.tled.integration = integration;
    ExplicitSolver s(model, c, o);
    const int ramp = 50, hold = 250;
    unsigned flags = kStepOk;
    for (int i = 1; i <= ramp + hold; ++i) {
        const double z = -0.01 * strain * std::min(1.0, static_cast<double>(i) / ramp);
        for (int n : top) s.setPrescribed(3 * n + 2, z);
        const StepResult r = s.step(1e-3);
        flags |= r.flags;
        if (last) *last = r;
    }
    if (last) last->flags = flags;
    return -s.reactionSum(top)[2];
}

}  // namespace palp::fem::test
