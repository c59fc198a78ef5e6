// TLED against CalculiX with geometric nonlinearity (NLGEOM, *HYPERELASTIC, NEO HOOKE): palp
// writes the .inp of its own cube, ccx solves it statically, palp's explicit solver settles the
// same cube to rest; the top reactions must agree.
#include <gtest/gtest.h>

#include <cmath>
#include <fstream>
#include <iostream>
#include <sstream>
#include <string>

#include "palp/base/error.h"
#include "palp/fem/calculix.h"
#include "palp/fem/tled.h"
#include "test_support.h"
#include "tled_fixtures.h"

namespace palp::fem {
namespace {

/// ccx's top reaction (N, positive in compression) of @p model held by @p c with the top face
/// driven down by @p strain.
double ccxTopReaction(const FemModel& model, Constraints c, double strain) {
    const std::vector<int> top = model.mesh().faceNodes(BoxFace::zMax);
    for (int n : top) c.prescribe(3 * n + 2, -0.01 * strain);
    palp::test::TempDir dir;
    CalculixStep step;
    step.staticIncrement = 0.1;
    step.printReactions = true;
    writeCalculixInput(dir / "job.inp", model, c, Eigen::VectorXd::Zero(model.dofCount()), step);
    const auto r = palp::test::runCommand("cd '" + dir.path().string() +
                                          "' && OMP_NUM_THREADS=1 ccx -i job 2>&1");
    EXPECT_EQ(r.exitCode, 0) << r.output;
    const CalculixResults res = readCalculixDat(dir / "job.dat", model.dofCount());
    EXPECT_FALSE(res.reactions.empty());
    if (res.reactions.empty()) return 0.0;
    EXPECT_NEAR(res.times.back(), 1.0, 1e-9) << "ccx reached the end of its step";
    double sum = 0.0;
    for (int n : top) sum += res.reactions.back()[3 * n + 2];
    return sum;
}

TEST(CalculixTled, WriterEmitsNeoHookeAndNlgeomWithFieldsThatFit) {
    const FemModel model(test::tledCube(), test::neoHookeanTissue());
    palp::test::TempDir dir;
    CalculixStep step;
    step.staticIncrement = 0.1;
    step.printReactions = true;
    writeCalculixInput(dir / "job.inp", model, Constraints(model.dofCount()),
                       Eigen::VectorXd::Zero(model.dofCount()), step);
    std::ifstream in(dir / "job.inp");
    std::stringstream text;
    text << in.rdbuf();
    const std::string inp = text.str();
    const NeoHookean law = NeoHookean::fromYoungs(test::kTledE, test::kTledNu);
    EXPECT_NE(inp.find("*HYPERELASTIC, NEO HOOKE\n" + calculixNumber(law.c10()) + ", " +
                       calculixNumber(law.d1()) + "\n"),
              std::string::npos)
        << inp.substr(0, 400);
    EXPECT_EQ(inp.find("*ELASTIC"), std::string::npos);
    EXPECT_NE(inp.find("*STEP, NLGEOM, INC=10000\n*STATIC\n0.1, 1\n"), std::string::npos);
    EXPECT_NE(inp.find("\nU, RF\n"), std::string::npos);
    EXPECT_LE(calculixNumber(law.d1()).size(), kCalculixNumberWidth);
    for (const double bad : {0.0, 1.5, std::nan("")}) {
        step.staticIncrement = bad;
        EXPECT_THROW(writeCalculixInput(dir / "bad.inp", model, Constraints(model.dofCount()),
                                        Eigen::VectorXd::Zero(model.dofCount()), step),
                     ValueError);
    }
    EXPECT_FALSE(std::filesystem::exists(dir / "bad.inp"));
}

TEST(CalculixTled, CubeBetweenRollersAndBondedPlatesMatchesCcxNlgeomNeoHooke) {
    // The issue's figures (ccx 2.20, C3D8): rollers 0.11180 / 0.25526 / 0.44926 N, bonded
    // 0.1541 / 0.3523 / 0.6178 N at 10 / 20 / 30 %.
    if (!palp::test::haveProgram("ccx")) GTEST_SKIP() << "ccx (Debian calculix-ccx) not installed";
    const double issue[2][3] = {{0.11180, 0.25526, 0.44926}, {0.1541, 0.3523, 0.6178}};
    const HexMesh mesh = test::tledCube(4);
    const FemModel model(mesh, test::neoHookeanTissue(600.0));
    for (const test::Plates plates : {test::Plates::rollers, test::Plates::bonded}) {
        const int p = plates == test::Plates::rollers ? 0 : 1;
        const Constraints c = test::plateConstraints(mesh, plates);
        for (int s = 0; s < 3; ++s) {
            const double strain = 0.1 * (s + 1);
            const double ccx = -ccxTopReaction(model, c, strain);
            EXPECT_NEAR(ccx, issue[p][s], 1e-3 * issue[p][s]) << "ccx as in the issue";
            StepResult lastOne, lastFull;
            const double one = test::settledTopReaction(
                model, c, strain, TledIntegration::onePointHourglass, &lastOne);
            const double full =
                test::settledTopReaction(model, c, strain, TledIntegration::gauss2x2x2, &lastFull);
            std::cout << "[ TLED vs ccx C3D8 NLGEOM NEO HOOKE ] " << (p == 0 ? "rollers" : "bonded")
                      << " " << 10 * (s + 1) << " %: ccx " << ccx << " N; palp 2x2x2 " << full
                      << " N (" << 100 * (full / ccx - 1) << " %), 1-point+hourglass " << one
                      << " N (" << 100 * (one / ccx - 1) << " %)\n";
            EXPECT_EQ(lastOne.flags, kStepOk);
            EXPECT_EQ(lastFull.flags, kStepOk);
            // 2x2x2 is C3D8's integration: the same discrete problem (measured: 6 digits).
            EXPECT_NEAR(full, ccx, 0.002 * ccx);
            if (plates == test::Plates::rollers) {
                EXPECT_NEAR(one, ccx, 0.002 * ccx) << "homogeneous: hourglass springs idle";
            } else {
                // One point locks less than C3D8 where the cube bulges: softer by 7 % with the
                // default kappa 0.1 (1.3 % at 20 % with kappa 0.2; Tled.OnePointAndFullConverge
                // shows the gap closing as the mesh is refined).
                EXPECT_LT(one, ccx);
                EXPECT_GT(one, 0.9 * ccx);
            }
        }
    }
}

}  // namespace
}  // namespace palp::fem
