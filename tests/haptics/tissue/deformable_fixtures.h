#pragma once
// Shared by the deformable tests: a soft 40 mm test cube (5 mm cells) pressed along +y, the
// quasi-static baseline, an Embree-independent inside test, VC parameters and a scene.
#include <array>
#include <chrono>
#include <cmath>
#include <iostream>
#include <limits>
#include <random>
#include <string>
#include <thread>
#include <vector>

#include "alloc_counter.h"
#include "palp/base/error.h"
#include "palp/fem/implicit_solver.h"
#include "palp/haptics/session.h"
#include "palp/haptics/tissue/deformable.h"
#include "palp/kernels/embree_scene.h"
#include "palp/volume/phantom.h"
#include "session_fixtures.h"

namespace palp::haptics::dfix {

using fixtures::kT;
using fixtures::PathDevice;
using fixtures::touchX;

inline Eigen::Vector3d mm(double x, double y, double z) { return 1e-3 * Eigen::Vector3d(x, y, z); }

// Soft cube, 40 mm, 9 nodes per axis (h = 5 mm): surface y = 0 facing -y (the phantoms'
// frame, pressed along +y), x and z in +-20 mm, fixed on its bottom face y = 40 mm.
inline fem::ElasticMaterial softTissue() {
    fem::ElasticMaterial m;
    m.youngsModulus = 5e3;
    m.poissonRatio = 0.45;
    m.density = 1e3;
    m.dampingAlpha = 60;  // about critical for the lowest modes: steady within ~0.3 s
    return m;
}

inline std::shared_ptr<DeformableModel> cube(double filterWidth, int nodes = 9) {
    DeformableOptions o;
    o.filterWidth = filterWidth;
    return DeformableModel::box(Eigen::Vector3d::Constant(0.04), {nodes, nodes, nodes},
                                softTissue(), fem::BoxFace::yMax, o, mm(-20, 0, -20));
}

inline int topCentreNode(const DeformableModel& m) {
    const fem::HexMesh& mesh = m.model().mesh();
    const auto c = mesh.nodeCounts();
    return mesh.node(c[0] / 2, 0, c[2] / 2);
}

// Quasi-static displacement under the nodal load @p f (the zero-error baseline).
inline Eigen::VectorXd quasiStatic(const DeformableModel& m, const Eigen::VectorXd& f) {
    fem::ImplicitOptions o;
    o.integrator = fem::Integrator::quasiStatic;
    o.solver = fem::LinearSolverKind::simplicialLdlt;
    fem::ImplicitSolver s(m.model(), m.constraints(), o);
    s.externalForce() = f;
    s.step(kT);
    return s.displacement();
}

// Ray parity (majority of three skew directions), in double precision and independent of
// Embree, against the surface of @p m displaced by @p u.
inline bool inside(const DeformableModel& m, const Eigen::VectorXd& u, const Eigen::Vector3d& p) {
    const fem::SurfaceMesh& sm = m.surface();
    std::vector<Eigen::Vector3d> x(sm.vertices.size());
    for (std::size_t i = 0; i < x.size(); ++i)
        x[i] = sm.vertices[i].cast<double>() + u.segment<3>(3 * sm.vertexNode[i]);
    const std::array<Eigen::Vector3d, 3> dirs = {Eigen::Vector3d(0.267261, 0.534522, 0.801784),
                                                 Eigen::Vector3d(-0.639602, 0.426401, 0.639602),
                                                 Eigen::Vector3d(0.562254, -0.749672, 0.349215)};
    int votes = 0;
    for (const Eigen::Vector3d& d : dirs) {
        int crossings = 0;
        for (const auto& t : sm.triangles) {
            // Moller-Trumbore.
            const Eigen::Vector3d &a = x[t[0]], &b = x[t[1]], &c = x[t[2]];
            const Eigen::Vector3d e1 = b - a, e2 = c - a, q = d.cross(e2);
            const double det = e1.dot(q);
            if (std::abs(det) < 1e-30) continue;
            const Eigen::Vector3d s = p - a;
            const double bu = s.dot(q) / det;
            const Eigen::Vector3d r = s.cross(e1);
            const double bv = d.dot(r) / det;
            const double tt = e2.dot(r) / det;
            if (bu >= 0 && bv >= 0 && bu + bv <= 1 && tt > 0) ++crossings;
        }
        votes += crossings % 2;
    }
    return votes >= 2;
}

inline SessionParams vcParams(double k = 300) {
    SessionParams p;
    p.coupling.mode = CouplingMode::VC;
    p.coupling.baseStiffness = k;
    p.coupling.maxStiffness = k;
    p.proxy.staticFriction = 0.5;
    p.proxy.dynamicFriction = 0.3;
    return p;
}

inline std::shared_ptr<Scene> deformableScene(std::shared_ptr<const DeformableModel> model) {
    auto scene = std::make_shared<Scene>();
    scene->commit();
    scene->setDeformable(std::move(model));
    return scene;
}

// (1) A constant force held on the explicit body settles where the implicit quasi-static

// Static nodal load of the body's contact: the filter's weights times @p force.
inline Eigen::VectorXd contactLoad(const DeformableBody& body, const Eigen::Vector3d& force) {
    Eigen::VectorXd f = Eigen::VectorXd::Zero(body.model().model().dofCount());
    for (std::size_t i = 0; i < body.loadedCount(); ++i)
        f.segment<3>(3 * body.loadedNodes()[i]) += body.loadedWeights()[i] * force;
    return f;
}

}  // namespace palp::haptics::dfix
