// Asynchronous regions with a neo-Hookean model (issue 36 item 2): TLED in the primary, the
// linear small-strain stiffness in the secondary. Against the whole mesh run by TLED: the same
// forces when the primary covers the mesh, and at 20 % indentation under a finger (a coupling
// spring on a Gaussian patch, as DeformableBody drives the regions) pressed and sliding.
#include <gtest/gtest.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <iostream>
#include <thread>
#include <vector>

#include "alloc_counter.h"
#include "fem_test_util.h"
#include "palp/fem/async_regions.h"
#include "palp/fem/explicit_solver.h"

namespace palp::fem {
namespace {

using test::peak;

constexpr double kTick = 1e-3;

ElasticMaterial tissue(MaterialLaw law, double alpha) {
    ElasticMaterial m{5e3, 0.45, 1e3, alpha, 0.0};
    m.law = law;
    return m;
}

/// Cube of n^3 nodes, h = 5 mm, bottom fixed.
struct Body {
    FemModel model;
    Constraints constraints;
    Body(int n, MaterialLaw law, double alpha)
        : model(HexMesh::box(Eigen::Vector3d::Constant(0.005 * (n - 1)), {n, n, n}, 5e3),
                tissue(law, alpha)),
          constraints(model.dofCount()) {
        constraints.fixNodes(model.mesh().faceNodes(BoxFace::zMin));
    }
    int n() const { return model.mesh().nodeCounts()[0]; }
    double height() const { return 0.005 * (n() - 1); }
};

TEST(AsyncTled, PrimaryCoveringTheMeshEqualsTheWholeMeshTled) {
    // Displacement drive, the top-centre node pressed 3 mm (60 % of a cell) at 2 Hz: with the
    // primary over the whole mesh and a solve every tick the regions are the explicit solver,
    // here its TLED path (substeps from the current state included).
    const Body b(7, MaterialLaw::neoHookean, 10.0);
    const int contact = b.model.mesh().node(3, 3, 6);
    Constraints c = b.constraints;
    for (int d = 0; d < 3; ++d) c.prescribe(3 * contact + d, 0.0);
    ExplicitSolver whole(b.model, c);
    AsyncRegionsOptions o;
    o.primaryNodes = b.model.mesh().nodeCount();
    o.secondaryRate = 1000.0;
    AsyncRegions a(b.model, b.constraints, {contact}, o);
    std::vector<double> ref, got;
    for (int t = 1; t <= 300; ++t) {
        const double z = -0.003 * 0.5 * (1.0 - std::cos(2.0 * M_PI * 2.0 * t * kTick));
        whole.setPrescribed(3 * contact + 2, z);
        whole.step(kTick);
        ref.push_back(-whole.reaction(3 * contact + 2));
        const AsyncTickResult r = a.tick(Eigen::Vector3d(0, 0, z));
        got.push_back(-r.contactForce.z());
    }
    for (std::size_t t = 0; t < ref.size(); ++t)
        ASSERT_NEAR(got[t], ref[t], 1e-9 * peak(ref)) << "tick " << t + 1;
    // And that is not the linear element's answer.
    const Body linear(7, MaterialLaw::linear, 10.0);
    ExplicitSolver lin(linear.model, c);
    double linPeak = 0.0;
    for (int t = 1; t <= 300; ++t) {
        lin.setPrescribed(3 * contact + 2,
                          -0.003 * 0.5 * (1.0 - std::cos(2.0 * M_PI * 2.0 * t * kTick)));
        lin.step(kTick);
        linPeak = std::max(linPeak, -lin.reaction(3 * contact + 2));
    }
    std::cout << "[ regions TLED, primary = mesh ] peak " << peak(ref) << " N, linear " << linPeak
              << " N\n";
    EXPECT_GT(std::abs(peak(ref) - linPeak), 0.01 * linPeak);
}

/// A finger on the top face as DeformableBody couples it: a spring (k 2,000 N/m, critically
/// damped) pulls the Gaussian-weighted displacement (sigma 5 mm, 3 sigma cut-off, weights on
/// the undeformed face) of the top nodes under the point down to the press depth, with no
/// tangential force.
struct Finger {
    const Body& body;
    std::vector<int> top;
    std::vector<int> nodes;
    std::vector<double> weights;
    CouplingSpring spring;
    explicit Finger(const Body& b) : body(b), top(b.model.mesh().faceNodes(BoxFace::zMax)) {
        nodes.reserve(top.size());
        weights.reserve(top.size());
    }
    /// The spring at point (x, y) (metres), pulling to @p depth with the tangential target at
    /// @p point (the weighted displacement at the last tick's end).
    const CouplingSpring& at(double x, double y, double depth, const Eigen::Vector3d& point) {
        const double sigma = 0.005;
        nodes.clear();
        weights.clear();
        double sum = 0.0;
        for (int n : top) {
            const Eigen::Vector3d p = body.model.mesh().nodePosition(n);
            const double r2 = (p.x() - x) * (p.x() - x) + (p.y() - y) * (p.y() - y);
            if (r2 > 9.0 * sigma * sigma) continue;
            nodes.push_back(n);
            weights.push_back(std::exp(-0.5 * r2 / (sigma * sigma)));
            sum += weights.back();
        }
        for (double& w : weights) w /= sum;
        spring.nodes = nodes;
        spring.weights = weights;
        spring.stiffness = 2000.0;
        spring.target = Eigen::Vector3d(point.x(), point.y(), -depth);
        spring.damping = criticalDamping(body.model, spring, 1.0);
        return spring;
    }
};

/// The finger's path: pressed at the centre to 20 % of the height over 400 ms, held 300 ms,
/// slid 20 mm along +x at 50 mm/s, held 200 ms.
struct Path {
    static constexpr int kPress = 400, kHold = 300, kSlide = 400, kRest = 200;
    static constexpr int kTicks = kPress + kHold + kSlide + kRest;
    double centre, height;
    double x(int t) const {
        const double s = std::clamp((t - kPress - kHold) / double(kSlide), 0.0, 1.0);
        return centre - 0.01 + 0.02 * s;
    }
    double fraction = 0.2;
    double depth(int t) const { return fraction * height * std::min(1.0, t / double(kPress)); }
};

struct FingerRun {
    std::vector<double> force;  // spring's mean force along -z, N
    int maxSubsteps = 0;
};

/// The whole mesh (ExplicitSolver, TLED for a neo-Hookean body) under the finger.
FingerRun wholeMesh(const Body& b, const Path& path) {
    ExplicitSolver s(b.model, b.constraints);
    Finger finger(b);
    FingerRun r;
    Eigen::Vector3d point = Eigen::Vector3d::Zero();
    for (int t = 1; t <= Path::kTicks; ++t) {
        SpringResult out;
        const StepResult step =
            s.step(kTick, finger.at(path.x(t), path.centre, path.depth(t), point), &out);
        EXPECT_EQ(step.flags, 0u) << "tick " << t;
        point = out.endPoint;
        r.force.push_back(-out.meanForce.z());
    }
    return r;
}

/// The regions (60 seeds, secondary at 100 Hz, synchronous) under the finger, asked for the
/// top node nearest the point 25 ms ahead as DeformableBody asks.
FingerRun regions(const Body& b, const Path& path) {
    AsyncRegionsOptions o;
    o.drive = ContactDrive::force;
    o.primaryNodes = 60;
    o.secondaryRate = 100.0;
    const HexMesh& mesh = b.model.mesh();
    const int n = b.n();
    auto nearest = [&](double x) {
        const int i = std::clamp(static_cast<int>(std::lround(x / 0.005)), 0, n - 1);
        return mesh.node(i, n / 2, n - 1);
    };
    AsyncRegions a(b.model, b.constraints, {nearest(path.x(0))}, o);
    Finger finger(b);
    FingerRun r;
    Eigen::Vector3d point = Eigen::Vector3d::Zero();
    for (int t = 1; t <= Path::kTicks; ++t) {
        const int want = nearest(path.x(t + 25));
        if (a.contactNodes().front() != want) a.requestContactNode(want);
        const AsyncTickResult res =
            a.tick({}, finger.at(path.x(t), path.centre, path.depth(t), point));
        EXPECT_EQ(res.flags & kStepSubstepLimit, 0u) << "tick " << t;
        point = res.spring.endPoint;
        r.force.push_back(-res.spring.meanForce.z());
        r.maxSubsteps = std::max(r.maxSubsteps, res.substeps);
    }
    return r;
}

double meanOver(const std::vector<double>& f, int from, int to) {
    double s = 0.0;
    for (int t = from; t < to; ++t) s += f[static_cast<std::size_t>(t)];
    return s / (to - from);
}

/// The force error over ticks [from, to): rms of the difference over the reference's rms (as
/// bench_async's "rms err"), and the largest relative difference and its tick.
struct SlideError {
    double rms = 0.0, largest = 0.0;
    int at = 0;
};
SlideError slideError(const FingerRun& got, const FingerRun& ref, int from, int to) {
    SlideError e;
    double diff2 = 0.0, ref2 = 0.0;
    for (int t = from; t < to; ++t) {
        const std::size_t k = static_cast<std::size_t>(t);
        const double d = got.force[k] - ref.force[k];
        diff2 += d * d;
        ref2 += ref.force[k] * ref.force[k];
        if (std::abs(d) / ref.force[k] > e.largest) {
            e.largest = std::abs(d) / ref.force[k];
            e.at = t + 1;
        }
    }
    e.rms = std::sqrt(diff2 / ref2);
    return e;
}

TEST(AsyncTled, TwentyPerCentIndentationPressedAndSlidingFollowsTheWholeMeshTled) {
    // The check: the force error of the regions (TLED primary, linear far field)
    // against the whole mesh run by TLED at 20 % indentation, static and sliding, at most 5 %.
    const Body b(9, MaterialLaw::neoHookean, 50.0);
    const Path path{0.02, b.height()};
    const FingerRun ref = wholeMesh(b, path);
    const FingerRun got = regions(b, path);
    const Body lb(9, MaterialLaw::linear, 50.0);
    const FingerRun lin = wholeMesh(lb, path);
    const int held = Path::kPress + Path::kHold, slid = held + Path::kSlide;
    const double refHeld = meanOver(ref.force, held - 50, held);
    const double gotHeld = meanOver(got.force, held - 50, held);
    const double linHeld = meanOver(lin.force, held - 50, held);
    const SlideError slide = slideError(got, ref, held, slid);
    const double slideErr = slide.rms;
    const double refEnd = meanOver(ref.force, Path::kTicks - 50, Path::kTicks);
    const double gotEnd = meanOver(got.force, Path::kTicks - 50, Path::kTicks);
    std::cout << "[ regions TLED, 20 % indentation ] held: whole-mesh TLED " << refHeld
              << " N, regions " << gotHeld << " N (" << 100.0 * (gotHeld / refHeld - 1.0)
              << " %), whole-mesh linear " << linHeld << " N; sliding: rms error "
              << 100.0 * slide.rms << " %, largest " << 100.0 * slide.largest << " % at tick "
              << slide.at << ", after it " << gotEnd << " vs " << refEnd
              << " N; regions substeps up to " << got.maxSubsteps << "\n";
    EXPECT_NEAR(gotHeld, refHeld, 0.05 * refHeld);
    EXPECT_LT(slideErr, 0.05);
    EXPECT_NEAR(gotEnd, refEnd, 0.05 * refEnd);
    // The law matters here: the linear body's force is further off than the regions'.
    EXPECT_GT(std::abs(linHeld - refHeld), 2.0 * std::abs(gotHeld - refHeld));
}

TEST(AsyncTled, ThreadedTickWithTheFingerAllocatesNothing) {
    // The servo's tick with a TLED primary under the finger: the substep from the current
    // state, TLED and linear cells, the spring; counted while the secondary thread is stalled.
    const Body b(9, MaterialLaw::neoHookean, 50.0);
    const Path path{0.02, b.height()};
    AsyncRegionsOptions o;
    o.drive = ContactDrive::force;
    o.primaryNodes = 60;
    o.secondaryRate = 100.0;
    o.threaded = true;
    AsyncRegions a(b.model, b.constraints, {b.model.mesh().node(4, 4, 8)}, o);
    Finger finger(b);
    Eigen::Vector3d point = Eigen::Vector3d::Zero();
    for (int t = 1; t <= 50; ++t)
        point = a.tick({}, finger.at(path.x(t), path.centre, path.depth(t), point)).spring.endPoint;
    a.setSecondaryStalledForTest(true);
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
    const std::uint64_t before = palp::test::allocationCount();
    int substeps = 0;
    for (int t = 51; t <= 300; ++t) {
        const AsyncTickResult r =
            a.tick({}, finger.at(path.x(t), path.centre, path.depth(t), point));
        point = r.spring.endPoint;
        substeps = std::max(substeps, r.substeps);
    }
    const std::uint64_t after = palp::test::allocationCount();
    a.setSecondaryStalledForTest(false);
    EXPECT_EQ(after - before, 0u);
    EXPECT_GT(substeps, 0);
}

}  // namespace
}  // namespace palp::fem
