// TLED (palp/fem/tled.h): the neo-Hookean stress against closed forms, the element's forces
// under rigid motion, rotation and small strain, the explicit solver's neo-Hookean path.
#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <algorithm>
#include <array>
#include <cmath>
#include <cstdlib>
#include <iostream>
#include <random>
#include <string>
#include <vector>

#include "alloc_counter.h"
#include "palp/base/error.h"
#include "palp/fem/async_regions.h"
#include "palp/fem/explicit_solver.h"
#include "palp/fem/implicit_solver.h"
#include "palp/fem/tled.h"
#include "tled_fixtures.h"

namespace palp::fem {
namespace {

constexpr double kE = test::kTledE, kNu = test::kTledNu;
using test::neoHookeanTissue;

/// Principal first Piola stress of the compressible neo-Hookean at stretches (l1, l2, l3):
/// Cauchy `sigma_i = mu J^(-5/3) (l_i^2 - I1 / 3) + K (J - 1)`, `P_i = J sigma_i / l_i`.
Eigen::Vector3d principalPiola(const Eigen::Vector3d& l, double mu, double bulk) {
    const double j = l.prod(), i1 = l.squaredNorm();
    Eigen::Vector3d p;
    for (int i = 0; i < 3; ++i) {
        const double sigma =
            mu * std::pow(j, -5.0 / 3.0) * (l[i] * l[i] - i1 / 3.0) + bulk * (j - 1.0);
        p[i] = j * sigma / l[i];
    }
    return p;
}

/// The lateral stretch of uniaxial stress at axial stretch @p l (P_xx = 0), by bisection.
double lateralStretch(double l, double mu, double bulk) {
    double a = 0.5, b = 2.0;
    for (int i = 0; i < 200; ++i) {
        const double m = 0.5 * (a + b);
        const double pa = principalPiola({a, a, l}, mu, bulk)[0];
        const double pm = principalPiola({m, m, l}, mu, bulk)[0];
        (pa * pm <= 0.0 ? b : a) = m;
    }
    return 0.5 * (a + b);
}

/// Displacement of every node of @p mesh under the map x = f(X).
template <class Map>
Eigen::VectorXd displacementOf(const HexMesh& mesh, Map map) {
    Eigen::VectorXd u = Eigen::VectorXd::Zero(mesh.dofCount());
    for (int n = 0; n < mesh.nodeCount(); ++n) {
        const Eigen::Vector3d x = mesh.nodePosition(n);
        u.segment<3>(3 * n) = map(x) - x;
    }
    return u;
}

/// A random deformed state of @p mesh: a random affine map of entries within +-@p strain plus
/// a random nodal jitter of up to 0.1 h, drawn from @p rng in that order.
Eigen::VectorXd randomDeformation(const HexMesh& mesh, double strain, std::mt19937& rng) {
    std::uniform_real_distribution<double> unit(-1.0, 1.0);
    Eigen::Matrix3d a;
    for (int i = 0; i < 9; ++i) a(i) = strain * unit(rng);
    Eigen::VectorXd u =
        displacementOf(mesh, [&](const Eigen::Vector3d& x) { return (x + a * x).eval(); });
    for (int d = 0; d < u.size(); ++d) u[d] += 0.1 * mesh.edge() * unit(rng);
    return u;
}

Eigen::VectorXd internalForces(const TledForces& t, const Eigen::VectorXd& u) {
    Eigen::VectorXd f = Eigen::VectorXd::Zero(u.size());
    t.addInternalForces(u.data(), f.data());
    return f;
}

constexpr TledIntegration kBoth[] = {TledIntegration::onePointHourglass,
                                     TledIntegration::gauss2x2x2};

TEST(NeoHookean, UniaxialFirstPiolaEqualsTheClosedFormAt10To30PerCent) {
    const NeoHookean law = NeoHookean::fromYoungs(kE, kNu);
    EXPECT_DOUBLE_EQ(law.c10(), 0.5 * kE / (2.0 * (1.0 + kNu)));
    EXPECT_DOUBLE_EQ(law.d1(), 2.0 * 3.0 * (1.0 - 2.0 * kNu) / kE);
    // The CalculiX reactions on a 1 cm^2 face, N, at 10 / 20 / 30 %.
    const double ccx[3] = {0.11180, 0.25526, 0.44926};
    for (int s = 0; s < 3; ++s) {
        const double l = 1.0 - 0.1 * (s + 1);
        const double lt = lateralStretch(l, law.mu, law.bulk);
        const Eigen::Matrix3d f = Eigen::Vector3d(lt, lt, l).asDiagonal();
        const Eigen::Matrix3d p = law.firstPiola(f);
        const Eigen::Vector3d closed = principalPiola({lt, lt, l}, law.mu, law.bulk);
        for (int i = 0; i < 3; ++i) {
            EXPECT_NEAR(p(i, i), closed[i], 1e-10 * std::abs(closed[2])) << "strain " << s;
            for (int j = 0; j < 3; ++j) {
                if (j != i) {
                    EXPECT_EQ(p(i, j), 0.0);
                }
            }
        }
        EXPECT_LT((f * law.secondPiola(f) - p).norm(), 1e-10 * p.norm()) << "P = F S";
        EXPECT_NEAR(-p(2, 2) * 1e-4, ccx[s], 5e-6) << "reaction on 1 cm^2 at " << 10 * (s + 1);
        std::cout << "[ uniaxial " << 10 * (s + 1) << " % ] lateral stretch " << lt << ", P_zz "
                  << p(2, 2) << " Pa, reaction " << -p(2, 2) * 1e-4 << " N\n";
    }
    // Uniaxial strain (no lateral stretch) too: a different closed-form state.
    for (const double l : {0.9, 0.8, 0.7}) {
        const Eigen::Matrix3d f = Eigen::Vector3d(1.0, 1.0, l).asDiagonal();
        const Eigen::Vector3d closed = principalPiola({1.0, 1.0, l}, law.mu, law.bulk);
        EXPECT_NEAR(law.firstPiola(f)(2, 2), closed[2], 1e-10 * std::abs(closed[2]));
        EXPECT_NEAR(law.firstPiola(f)(0, 0), closed[0], 1e-10 * std::abs(closed[2]));
    }
}

TEST(Tled, HomogeneousCompressionForcesAreThoseOfTheClosedFormStress) {
    // A 3^3-cell cube deformed by x = diag(lt, lt, l) X: every interior node is in equilibrium
    // and the top face carries P_zz times its area, in both integrations (the deformation is
    // affine, so the hourglass springs are idle).
    const HexMesh mesh = HexMesh::box(Eigen::Vector3d::Constant(0.01), {4, 4, 4}, kE);
    const FemModel model(mesh, neoHookeanTissue());
    const NeoHookean law = NeoHookean::fromYoungs(kE, kNu);
    for (const TledIntegration integration : kBoth) {
        const TledForces tled(model, {integration, 0.1});
        for (int s = 1; s <= 3; ++s) {
            const double l = 1.0 - 0.1 * s, lt = lateralStretch(l, law.mu, law.bulk);
            const Eigen::VectorXd u = displacementOf(mesh, [&](const Eigen::Vector3d& x) {
                return Eigen::Vector3d(lt * x.x(), lt * x.y(), l * x.z()).eval();
            });
            const Eigen::VectorXd f = internalForces(tled, u);
            double top = 0.0, interior = 0.0, side = 0.0;
            for (int n : mesh.faceNodes(BoxFace::zMax)) top += f[3 * n + 2];
            for (int k = 1; k < 3; ++k) {
                for (int j = 1; j < 3; ++j) {
                    for (int i = 1; i < 3; ++i)
                        interior = std::max(interior, f.segment<3>(3 * mesh.node(i, j, k)).norm());
                }
            }
            for (int n : mesh.faceNodes(BoxFace::xMax)) side += f[3 * n];
            const double pzz = principalPiola({lt, lt, l}, law.mu, law.bulk)[2];
            EXPECT_NEAR(top, pzz * 1e-4, 1e-10 * std::abs(pzz) * 1e-4) << s;
            EXPECT_LT(interior, 1e-10 * std::abs(pzz) * 1e-4);
            EXPECT_LT(std::abs(side), 1e-10 * std::abs(pzz) * 1e-4) << "uniaxial stress";
        }
    }
}

TEST(Tled, RigidMotionGivesNoForceAndTheForcesAreObjective) {
    const double h = 1e-3;
    // Rows of 6 cells: the one-point kernel's four-cell path and its one-by-one rest.
    const HexMesh mesh = HexMesh::box(Eigen::Vector3d(6 * h, 3 * h, 3 * h), {7, 4, 4}, kE,
                                      Eigen::Vector3d(-0.002, 0.001, 0.0005));
    const FemModel model(mesh, neoHookeanTissue());
    const Eigen::Matrix3d q =
        Eigen::AngleAxisd(0.5 * M_PI, Eigen::Vector3d(1, 2, 3).normalized()).toRotationMatrix();
    const Eigen::Vector3d t(0.004, -0.003, 0.002);
    std::mt19937 rng(36);
    std::uniform_real_distribution<double> unit(-1.0, 1.0);
    // A random deformed state: 15 % affine strain plus 0.1 h random nodal jitter.
    Eigen::VectorXd u = randomDeformation(mesh, 0.15, rng);
    for (const TledIntegration integration : kBoth) {
        const TledForces tled(model, {integration, 0.1});
        const Eigen::VectorXd rigid =
            displacementOf(mesh, [&](const Eigen::Vector3d& x) { return (q * x + t).eval(); });
        const double rigidForce = internalForces(tled, rigid).cwiseAbs().maxCoeff();
        EXPECT_LT(rigidForce, 1e-12 * kE * h * h);
        // x' = Q x + t of the deformed state: the forces turn with it.
        const Eigen::VectorXd f = internalForces(tled, u);
        Eigen::VectorXd uRot(u.size());
        for (int n = 0; n < mesh.nodeCount(); ++n) {
            const Eigen::Vector3d x = mesh.nodePosition(n) + u.segment<3>(3 * n);
            uRot.segment<3>(3 * n) = q * x + t - mesh.nodePosition(n);
        }
        const Eigen::VectorXd fRot = internalForces(tled, uRot);
        double worst = 0.0;
        for (int n = 0; n < mesh.nodeCount(); ++n)
            worst = std::max(worst, (fRot.segment<3>(3 * n) - q * f.segment<3>(3 * n)).norm());
        const double scale = f.cwiseAbs().maxCoeff();
        std::cout << "[ TLED rigid/objectivity, "
                  << (integration == TledIntegration::gauss2x2x2 ? "2x2x2" : "1-point+hourglass")
                  << " ] rigid force " << rigidForce / (kE * h * h) << " E h^2, |f(Qx) - Q f(x)| "
                  << worst / scale << " of max |f|\n";
        EXPECT_GT(scale, 1e-3 * kE * h * h) << "a deformed state";
        EXPECT_LT(worst, 1e-12 * scale);
        // The energy is invariant too.
        EXPECT_NEAR(tled.strainEnergy(uRot.data()), tled.strainEnergy(u.data()),
                    1e-12 * tled.strainEnergy(u.data()));
    }
}

/// The one-point element written out per cell as tled.h states it: F = I + sum_a u_a grad_a^T
/// with grad_a = s_a / (4 h), f_a += h^3 P grad_a plus the hourglass springs
/// kappa (K + 4/3 mu) h E on the four unit sign-product vectors of the cube, per component.
Eigen::VectorXd onePointReference(const HexMesh& mesh, double nu, double kappa,
                                  const Eigen::VectorXd& u) {
    const double h = mesh.edge();
    const NeoHookean unit = NeoHookean::fromYoungs(1.0, nu);
    const double spring = kappa * (unit.bulk + 4.0 / 3.0 * unit.mu) * h;
    Eigen::VectorXd f = Eigen::VectorXd::Zero(u.size());
    const std::array<int, 3> cells = mesh.cellCounts();
    for (int k = 0; k < cells[2]; ++k) {
        for (int j = 0; j < cells[1]; ++j) {
            for (int i = 0; i < cells[0]; ++i) {
                const double e =
                    mesh.cellYoungs()[static_cast<std::size_t>(i + cells[0] * (j + cells[1] * k))];
                if (e == 0.0) continue;
                int node[8];
                Eigen::Vector3d sign[8];
                Eigen::Matrix3d f0 = Eigen::Matrix3d::Identity();
                for (int a = 0; a < 8; ++a) {
                    node[a] = mesh.node(i + (a & 1), j + (a >> 1 & 1), k + (a >> 2 & 1));
                    sign[a] = Eigen::Vector3d((a & 1) ? 1 : -1, (a & 2) ? 1 : -1, (a & 4) ? 1 : -1);
                    f0 += u.segment<3>(3 * node[a]) * (sign[a] / (4.0 * h)).transpose();
                }
                const Eigen::Matrix3d p = NeoHookean{e * unit.mu, e * unit.bulk}.firstPiola(f0);
                for (int mode = 0; mode < 4; ++mode) {
                    Eigen::Vector3d q = Eigen::Vector3d::Zero();
                    double g[8];
                    for (int a = 0; a < 8; ++a) {
                        const Eigen::Vector3d& s = sign[a];
                        g[a] = (mode == 0   ? s.y() * s.z()
                                : mode == 1 ? s.x() * s.z()
                                : mode == 2 ? s.x() * s.y()
                                            : s.x() * s.y() * s.z()) /
                               std::sqrt(8.0);
                        q += g[a] * u.segment<3>(3 * node[a]);
                    }
                    for (int a = 0; a < 8; ++a) f.segment<3>(3 * node[a]) += e * spring * g[a] * q;
                }
                for (int a = 0; a < 8; ++a)
                    f.segment<3>(3 * node[a]) += h * h * h * p * (sign[a] / (4.0 * h));
            }
        }
    }
    return f;
}

TEST(Tled, OnePointForcesEqualTheElementWrittenOutOnRowsOfEveryLength) {
    // The one-point kernel takes four cells of a lattice row at a time where the CPU allows
    // (AVX2+FMA; `portable.fem_tled` runs this with PALP_SIMD=off) and the rest one by one:
    // rows of 1 to 9 cells, a third of the cells void, moduli from 1x to 3x, 25 % strain plus
    // jitter, against the element written out above.
    std::mt19937 rng(361);
    std::uniform_real_distribution<double> unit(-1.0, 1.0);
    const double h = 2e-3;
    for (int cx = 1; cx <= 9; ++cx) {
        std::vector<double> youngs(static_cast<std::size_t>(cx * 3 * 2));
        for (double& e : youngs) e = unit(rng) < -0.33 ? 0.0 : kE * (2.0 + unit(rng));
        youngs[0] = kE;
        const HexMesh mesh =
            HexMesh::fromCells({cx + 1, 4, 3}, h, Eigen::Vector3d(0.01, 0, 0), youngs);
        const FemModel model(mesh, neoHookeanTissue());
        const Eigen::VectorXd u = randomDeformation(mesh, 0.25, rng);
        const TledForces tled(model, {TledIntegration::onePointHourglass, 0.1});
        const Eigen::VectorXd f = internalForces(tled, u);
        const Eigen::VectorXd ref = onePointReference(mesh, kNu, 0.1, u);
        ASSERT_GT(ref.cwiseAbs().maxCoeff(), 1e-3 * kE * h * h) << "a deformed state";
        EXPECT_LT((f - ref).cwiseAbs().maxCoeff(), 1e-12 * ref.cwiseAbs().maxCoeff())
            << cx << " cells a row";
        // Forces on no node that only void cells touch.
        for (int n = 0; n < mesh.nodeCount(); ++n) {
            if (ref.segment<3>(3 * n).isZero(0.0)) {
                EXPECT_TRUE(f.segment<3>(3 * n).isZero(0.0)) << n;
            }
        }
    }
}

TEST(Tled, CellListForcesAddUpToTheWholeMeshsInAnyOrder) {
    // addCellForces (the regions' primary: a list of cells, four-cell row runs and any other
    // four at a time) over a random split of the cells, each half shuffled but for some runs
    // kept in order, adds up to addInternalForces; both integrations, 25 % strain.
    std::mt19937 rng(362);
    std::uniform_real_distribution<double> unit(-1.0, 1.0);
    const double h = 2e-3;
    const std::array<int, 3> nodes{9, 5, 4};
    std::vector<double> youngs(static_cast<std::size_t>(8 * 4 * 3));
    for (double& e : youngs) e = unit(rng) < -0.5 ? 0.0 : kE * (2.0 + unit(rng));
    youngs[0] = kE;
    const HexMesh mesh = HexMesh::fromCells(nodes, h, Eigen::Vector3d::Zero(), youngs);
    const FemModel model(mesh, neoHookeanTissue());
    const Eigen::VectorXd u = randomDeformation(mesh, 0.25, rng);
    for (const TledIntegration integration : kBoth) {
        const TledForces tled(model, {integration, 0.1});
        const Eigen::VectorXd whole = internalForces(tled, u);
        std::array<std::vector<std::array<int, 8>>, 2> dofs;
        std::array<std::vector<double>, 2> moduli;
        for (int c = 0; c < mesh.cellCount();) {
            // Runs of 1 to 6 cells in order, each to a random half.
            const int run = 1 + static_cast<int>(rng() % 6);
            const std::size_t half = rng() % 2;
            for (int r = 0; r < run && c < mesh.cellCount(); ++r, ++c) {
                std::array<int, 8> d{};
                const auto cn = mesh.cellNodes(c);
                for (int k = 0; k < 8; ++k)
                    d[static_cast<std::size_t>(k)] = 3 * cn[static_cast<std::size_t>(k)];
                dofs[half].push_back(d);
                moduli[half].push_back(youngs[static_cast<std::size_t>(c)]);
            }
        }
        Eigen::VectorXd f = Eigen::VectorXd::Zero(u.size());
        for (std::size_t half = 0; half < 2; ++half)
            tled.addCellForces(u.data(), f.data(), dofs[half], moduli[half]);
        EXPECT_LT((f - whole).cwiseAbs().maxCoeff(), 1e-12 * whole.cwiseAbs().maxCoeff());
        // In reverse order (no runs: every cell through the four-anywhere path).
        for (std::size_t half = 0; half < 2; ++half) {
            std::reverse(dofs[half].begin(), dofs[half].end());
            std::reverse(moduli[half].begin(), moduli[half].end());
        }
        f.setZero();
        for (std::size_t half = 0; half < 2; ++half)
            tled.addCellForces(u.data(), f.data(), dofs[half], moduli[half]);
        EXPECT_LT((f - whole).cwiseAbs().maxCoeff(), 1e-12 * whole.cwiseAbs().maxCoeff());
        // The frequency bound over all cells is the whole mesh's.
        std::vector<std::array<int, 8>> all = dofs[0];
        all.insert(all.end(), dofs[1].begin(), dofs[1].end());
        std::vector<double> allE = moduli[0];
        allE.insert(allE.end(), moduli[1].begin(), moduli[1].end());
        EXPECT_NEAR(tled.frequencyBoundCells(u.data(), all, allE), tled.frequencyBound(u.data()),
                    1e-12 * tled.frequencyBound(u.data()));
    }
}

TEST(Tled, SmallStrainForcesEqualTheLinearElementsToSecondOrder) {
    const HexMesh mesh = HexMesh::box(Eigen::Vector3d::Constant(0.01), {5, 5, 5}, kE);
    const FemModel model(mesh, neoHookeanTissue());
    std::mt19937 rng(7);
    std::uniform_real_distribution<double> unit(-1.0, 1.0);
    Eigen::VectorXd random(mesh.dofCount());
    for (int d = 0; d < random.size(); ++d) random[d] = unit(rng);
    Eigen::Matrix3d a;
    for (int i = 0; i < 9; ++i) a(i) = unit(rng);
    const Eigen::VectorXd affine =
        displacementOf(mesh, [&](const Eigen::Vector3d& x) { return (x + a * x).eval(); });
    // 2x2x2 on any field (its tangent at rest is the linear C3D8's); the one-point element on
    // an affine field (the hourglass springs are idle and one point integrates it exactly).
    struct Case {
        TledIntegration integration;
        const Eigen::VectorXd* shape;
        double perStrain;  // displacement scale per unit strain
    };
    const Case cases[] = {{TledIntegration::gauss2x2x2, &random, mesh.edge()},
                          {TledIntegration::onePointHourglass, &affine, 1.0},
                          {TledIntegration::gauss2x2x2, &affine, 1.0}};
    for (const Case& c : cases) {
        const TledForces tled(model, {c.integration, 0.1});
        double previous = 0.0;
        for (const double strain : {1e-2, 1e-3, 1e-4, 1e-5}) {
            const Eigen::VectorXd u = strain * c.perStrain * *c.shape;
            Eigen::VectorXd linear = Eigen::VectorXd::Zero(u.size());
            model.addStiffnessTimes(u.data(), linear.data());
            const double rel = (internalForces(tled, u) - linear).norm() / linear.norm();
            std::cout << "[ TLED vs linear ] strain " << strain << ": relative difference " << rel
                      << "\n";
            if (previous > 0.0) {
                // O(strain^2) in the force: the relative difference falls 10x per 10x.
                EXPECT_NEAR(rel / previous, 0.1, 0.02) << "strain " << strain;
            }
            EXPECT_LT(rel, 3.0 * strain);
            previous = rel;
        }
    }
}

TEST(Tled, RestFrequencyBoundIsTheLinearOneAndCompressionRaisesIt) {
    const HexMesh mesh = HexMesh::box(Eigen::Vector3d::Constant(0.01), {5, 5, 5}, kE);
    const FemModel model(mesh, neoHookeanTissue());
    const TledForces full(model, {TledIntegration::gauss2x2x2, 0.1});
    const TledForces one(model, {TledIntegration::onePointHourglass, 0.1});
    const Eigen::VectorXd rest = Eigen::VectorXd::Zero(mesh.dofCount());
    EXPECT_DOUBLE_EQ(full.frequencyBound(rest.data()), model.maxFrequencyBound());
    EXPECT_DOUBLE_EQ(one.frequencyBound(rest.data()), one.restFrequencyBound());
    std::cout << "[ TLED rest frequency bound ] 1-point+hourglass "
              << one.restFrequencyBound() / model.maxFrequencyBound() << " x the 2x2x2 one\n";
    EXPECT_LE(one.restFrequencyBound(), 1.000001 * model.maxFrequencyBound());
    EXPECT_GT(one.restFrequencyBound(), 0.5 * model.maxFrequencyBound());
    double previous = model.maxFrequencyBound();
    for (const double l : {0.9, 0.8, 0.7, 0.5}) {
        const Eigen::VectorXd u = displacementOf(mesh, [&](const Eigen::Vector3d& x) {
            return Eigen::Vector3d(x.x(), x.y(), l * x.z()).eval();
        });
        const double w = full.frequencyBound(u.data());
        std::cout << "[ TLED frequency bound ] stretch " << l << ": "
                  << w / model.maxFrequencyBound() << " x the rest bound\n";
        EXPECT_GT(w, previous);
        previous = w;
    }
}

TEST(Tled, ExplicitSolverRunsTheRollerCubeToTheClosedForm) {
    const NeoHookean law = NeoHookean::fromYoungs(kE, kNu);
    for (const TledIntegration integration : kBoth) {
        for (int s = 1; s <= 3; ++s) {
            const double l = 1.0 - 0.1 * s;
            const double closed = -1e-4 * principalPiola({lateralStretch(l, law.mu, law.bulk),
                                                          lateralStretch(l, law.mu, law.bulk), l},
                                                         law.mu, law.bulk)[2];
            StepResult last;
            const HexMesh mesh = test::tledCube();
            const FemModel model(mesh, test::neoHookeanTissue(600.0));
            const double r =
                test::settledTopReaction(model, test::plateConstraints(mesh, test::Plates::rollers),
                                         0.1 * s, integration, &last);
            std::cout << "[ TLED roller cube ] " << 10 * s << " %: reaction " << r
                      << " N, closed form " << closed << " N (" << 100 * (r / closed - 1) << " %), "
                      << last.substeps << " substeps per 1 ms\n";
            EXPECT_EQ(last.flags, kStepOk);
            EXPECT_NEAR(r, closed, 1e-4 * closed);
        }
    }
}

TEST(Tled, OnePointAndFullIntegrationConvergeUnderRefinement) {
    // The bonded cube at 20 %: 2x2x2 (C3D8) locks at nu 0.45 and is stiffer on a coarse mesh
    // than one point with hourglass control; refining the mesh closes the gap.
    double gap[2] = {};
    for (int level = 0; level < 2; ++level) {
        const HexMesh mesh = test::tledCube(4 << level);
        const FemModel model(mesh, test::neoHookeanTissue(600.0));
        const Constraints c = test::plateConstraints(mesh, test::Plates::bonded);
        StepResult a, b;
        const double one =
            test::settledTopReaction(model, c, 0.2, TledIntegration::onePointHourglass, &a);
        const double full =
            test::settledTopReaction(model, c, 0.2, TledIntegration::gauss2x2x2, &b);
        EXPECT_EQ(a.flags | b.flags, kStepOk);
        gap[level] = full / one - 1.0;
        std::cout << "[ TLED bonded cube 20 %, " << (4 << level) << "^3 cells ] 2x2x2 " << full
                  << " N, 1-point+hourglass " << one << " N (2x2x2 " << 100 * gap[level]
                  << " % stiffer)\n";
    }
    EXPECT_GT(gap[0], 0.0);
    EXPECT_LT(std::abs(gap[1]), 0.7 * std::abs(gap[0]));
}

TEST(Tled, NeoHookeanStepAllocatesNothingAndShortensItsSubstepUnderCompression) {
    const HexMesh mesh = HexMesh::box(Eigen::Vector3d::Constant(0.01), {5, 5, 5}, kE);
    const FemModel model(mesh, neoHookeanTissue(600.0));
    Constraints c(mesh.dofCount());
    c.fixNodes(mesh.faceNodes(BoxFace::zMin));
    const std::vector<int> top = mesh.faceNodes(BoxFace::zMax);
    c.fixNodes(top, 4u);
    ExplicitSolver s(model, c);
    ASSERT_NE(s.tled(), nullptr);
    const double restDt = s.stableTimeStep();
    auto press = [&](ExplicitSolver& solver, int i) {
        for (int n : top)
            solver.setPrescribed(3 * n + 2, -0.004 * std::min(1.0, static_cast<double>(i) / 50));
    };
    const std::uint64_t before = palp::test::allocationCount();
    StepResult r;
    for (int i = 1; i <= 100; ++i) {
        press(s, i);
        r = s.step(1e-3);
    }
    (void)s.strainEnergy();
    EXPECT_EQ(palp::test::allocationCount() - before, 0u);
    EXPECT_EQ(r.flags, kStepOk);
    std::cout << "[ TLED substep ] rest " << restDt << " s, at 40 % compression "
              << s.stableTimeStep() << " s\n";
    EXPECT_LT(s.stableTimeStep(), restDt);
    // The parallel step gives the serial one's state (the same sums in another order).
    ExplicitSolver p(model, c);
    ExplicitSolver q(model, c);
    for (int i = 1; i <= 20; ++i) {
        press(p, i);
        press(q, i);
        p.step(1e-3);
        q.stepParallel(1e-3);
    }
    EXPECT_LT((p.displacement() - q.displacement()).cwiseAbs().maxCoeff(),
              1e-12 * p.displacement().cwiseAbs().maxCoeff());
}

TEST(Tled, TooFewSubstepsAreCappedAndFlaggedAsForALinearModel) {
    // maxSubsteps 2 against a 2 ms tick (about 10 rest substeps): each step takes 2 substeps of
    // the current stable step, advances less time than asked and says so, and stays finite.
    const HexMesh mesh = test::tledCube();
    const FemModel model(mesh, neoHookeanTissue(600.0));
    const Constraints c = test::plateConstraints(mesh, test::Plates::bonded);
    ExplicitOptions o;
    o.maxSubsteps = 2;
    ExplicitSolver s(model, c, o);
    const std::vector<int> top = mesh.faceNodes(BoxFace::zMax);
    for (int i = 1; i <= 200; ++i) {
        for (int n : top) s.setPrescribed(3 * n + 2, -0.003 * std::min(1.0, i / 100.0));
        const StepResult r = s.step(2e-3);
        ASSERT_EQ(r.flags, kStepSubstepLimit) << "step " << i;
        ASSERT_EQ(r.substeps, 2);
        ASSERT_LE(r.advancedSeconds, 2.0 * s.stableTimeStep() * (1 + 1e-12));
    }
    EXPECT_TRUE(s.displacement().allFinite());
    EXPECT_GT(s.displacement().cwiseAbs().maxCoeff(), 1e-3);
}

TEST(Tled, LinearMaterialStepIsUnchangedAndTheImplicitSolverRefusesNeoHookean) {
    const HexMesh mesh = HexMesh::box(Eigen::Vector3d::Constant(0.01), {5, 5, 5}, kE);
    ElasticMaterial linear = neoHookeanTissue(50.0);
    linear.law = MaterialLaw::linear;
    const FemModel model(mesh, linear);
    Constraints c(mesh.dofCount());
    c.fixNodes(mesh.faceNodes(BoxFace::zMin));
    ExplicitSolver s(model, c);
    EXPECT_EQ(s.tled(), nullptr);
    EXPECT_EQ(s.stableTimeStep(), 0.9 * model.criticalTimeStep());
    const FemModel nh(mesh, neoHookeanTissue());
    EXPECT_THROW(ImplicitSolver(nh, c, {Integrator::quasiStatic, LinearSolverKind::cholmod}),
                 ValueError);
    // The regions take it (TLED primary, linear secondary: tests/fem/regions/test_async_tled.cpp)
    // and check its TLED options as the explicit solver does.
    ExplicitOptions o;
    o.tled.hourglassKappa = 2.0;
    EXPECT_THROW(ExplicitSolver(nh, c, o), ValueError);
    AsyncRegionsOptions ro;
    ro.tled.hourglassKappa = 2.0;
    EXPECT_THROW(AsyncRegions(nh, c, {mesh.node(2, 2, 4)}, ro), ValueError);
}

}  // namespace
}  // namespace palp::fem
