// The plain (staggered) coupling's stability: the spectral radius of its period map
// (palp/fem/async_stability.h) against runs of AsyncRegions on the 13^3 cube at 500 Hz, with the
// thesis's interpolation (diverges) and with the lead (bounded, near the whole-mesh force).
#include <gtest/gtest.h>

#include <cmath>
#include <numbers>

#include "fem_test_util.h"
#include "palp/fem/async_regions.h"
#include "palp/fem/async_stability.h"
#include "palp/fem/explicit_solver.h"

namespace palp::fem {
namespace {

using test::peak;
using test::rmsError;

constexpr int kTicks = 500;  // 0.5 s: the 1 Hz raised cosine up to its peak

/// bench_async's cube: 13^3 nodes, h 5 mm, E 5 kPa, nu 0.45, alpha 10/s, bottom fixed, the top
/// centre pressed 3 mm by a 1 Hz raised cosine.
struct Cube {
    FemModel model{HexMesh::box(Eigen::Vector3d::Constant(0.06), {13, 13, 13}, 5e3),
                   ElasticMaterial{5e3, 0.45, 1e3, 10.0, 0.0}};
    Constraints constraints{model.dofCount()};
    int contact = model.mesh().node(6, 6, 12);
    Cube() { constraints.fixNodes(model.mesh().faceNodes(BoxFace::zMin)); }
    static double press(int tick) {
        return -0.003 * 0.5 * (1.0 - std::cos(2.0 * std::numbers::pi * tick * 1e-3));
    }
};

/// The plain coupling at N 30 seeds, 500 Hz, quasi-static (the layout's own factorisation).
AsyncRegionsOptions plain500(double lead) {
    AsyncRegionsOptions o;
    o.primaryNodes = 30;
    o.secondaryRate = 500.0;
    o.condensed = false;
    o.plainLead = lead;
    o.globalSecondary = false;
    return o;
}

std::vector<double> run(const Cube& c, const AsyncRegionsOptions& o) {
    AsyncRegions a(c.model, c.constraints, {c.contact}, o);
    std::vector<double> f;
    for (int t = 1; t <= kTicks; ++t)
        f.push_back(-a.tick(Eigen::Vector3d(0, 0, Cube::press(t))).contactForce.z());
    return f;
}

std::vector<double> reference(const Cube& c) {
    Constraints k = c.constraints;
    for (int d = 0; d < 3; ++d) k.prescribe(3 * c.contact + d, 0.0);
    ExplicitSolver s(c.model, k);
    std::vector<double> f;
    for (int t = 1; t <= kTicks; ++t) {
        s.setPrescribed(3 * c.contact + 2, Cube::press(t));
        s.step(1e-3);
        f.push_back(-s.reaction(3 * c.contact + 2));
    }
    return f;
}

/// Largest |F| over the secondary periods [from, to) (2 ticks each).
double peakOver(const std::vector<double>& f, int from, int to) {
    double p = 0.0;
    for (int t = 2 * from; t < 2 * to; ++t)
        p = std::max(p, std::abs(f[static_cast<std::size_t>(t)]));
    return p;
}

TEST(AsyncStability, ThesisInterpolationDivergesAt500HzAtTheRateItsPeriodMapPredicts) {
    const Cube c;
    // Arnoldi on the matrix-free map (the dense 768 x 768 eigenvalues take seconds more).
    const StaggeredStability s =
        staggeredStability(c.model, c.constraints, {c.contact}, plain500(-1.0), 0);
    EXPECT_EQ(s.periodTicks, 2);
    EXPECT_GT(s.spectralRadius, 1.05);
    EXPECT_NEAR(s.growthPerPeriod, s.spectralRadius, 0.01 * s.spectralRadius);
    const std::vector<double> f = run(c, plain500(-1.0));
    const std::vector<double> ref = reference(c);
    EXPECT_GT(peak(f), 1e3 * peak(ref));  // diverged
    // Grown from the input's excitation: its rate per period is the spectral radius.
    const double growth = std::pow(peakOver(f, 200, 250) / peakOver(f, 150, 200), 1.0 / 50.0);
    EXPECT_NEAR(growth, s.spectralRadius, 0.02 * s.spectralRadius);
}

TEST(AsyncStability, LeadKeepsThePlainCouplingBoundedAt500HzNearTheWholeMesh) {
    const Cube c;
    const StaggeredStability s =
        staggeredStability(c.model, c.constraints, {c.contact}, plain500(0.5), 0);
    EXPECT_LT(s.spectralRadius, 1.0);
    EXPECT_LT(s.growthPerPeriod, 1.0);
    const std::vector<double> f = run(c, plain500(0.5));
    const std::vector<double> ref = reference(c);
    // Bounded and within the thesis's N 30 / 500 Hz error (0.5 %) of the whole mesh's peak.
    EXPECT_LT(std::abs(peak(f) - peak(ref)), 0.005 * peak(ref));
    EXPECT_LT(rmsError(f, ref), 0.02);
}

}  // namespace
}  // namespace palp::fem
