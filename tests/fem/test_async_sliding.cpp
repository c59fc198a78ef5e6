// Asynchronous regions under a sliding contact (issue 18): the capacitance secondary (one
// factorisation of the whole body) gives the same regions and forces as a factorisation per
// layout, every request is adopted within a secondary period, and the force follows the
// whole-mesh explicit solution whose contact moves at the same ticks.
#include <gtest/gtest.h>

#include <cmath>
#include <numbers>

#include "fem_test_util.h"
#include "palp/fem/async_regions.h"

namespace palp::fem {
namespace {

using test::peak;
using test::rmsError;

constexpr double kTick = 1e-3;

/// Cube of n^3 nodes, h = 5 mm, 5 kPa tissue with mass-proportional damping, bottom fixed.
struct Problem {
    FemModel model;
    Constraints constraints;
    int n;
    Problem(int nodes, double alpha)
        : model(HexMesh::box(Eigen::Vector3d::Constant(0.005 * (nodes - 1)), {nodes, nodes, nodes},
                             5e3),
                ElasticMaterial{5e3, 0.45, 1e3, alpha, 0.0}),
          constraints(model.dofCount()),
          n(nodes) {
        constraints.fixNodes(model.mesh().faceNodes(BoxFace::zMin));
    }
    int top(int x) const { return model.mesh().node(x, n / 2, n - 1); }
};

/// Raised-cosine press of 3 mm along -z at 1 Hz.
double press(double t) { return -0.003 * 0.5 * (1.0 - std::cos(2.0 * std::numbers::pi * t)); }

/// Whole-mesh central difference (ExplicitSolver's scheme: lumped mass, mass-proportional
/// damping) whose driven node can change: the old one is released with its displacement and
/// velocity, the new one moves from its displacement to the tick's target within the tick (the
/// switch of AsyncRegions).
class MovingWholeMesh {
  public:
    explicit MovingWholeMesh(const Problem& p)
        : mP(p), mU(Eigen::VectorXd::Zero(p.model.dofCount())), mUp(mU), mF(mU) {
        const double critical = 0.9 * p.model.criticalTimeStep();
        mSubsteps = std::max(1, static_cast<int>(std::ceil(kTick / critical)));
    }
    /// One tick with @p contact driven to (0, 0, @p z); @return the z reaction pushing in.
    double tick(int contact, double z) {
        const FemModel& m = mP.model;
        const Eigen::VectorXd& mass = m.lumpedMass();
        const double dt = kTick / mSubsteps, alpha = m.material().dampingAlpha;
        const Eigen::Vector3d start = mU.segment<3>(3 * contact), target(0, 0, z);
        for (int s = 0; s < mSubsteps; ++s) {
            mF.setZero();
            m.addStiffnessTimes(mU.data(), mF.data());
            for (int d = 0; d < m.dofCount(); ++d) {
                if (mP.constraints.isFixed(d) || mass[d] <= 0.0) continue;
                mUp[d] = (-dt * dt * mF[d] + 2.0 * mass[d] * mU[d] -
                          (1.0 - 0.5 * dt * alpha) * mass[d] * mUp[d]) /
                         ((1.0 + 0.5 * dt * alpha) * mass[d]);
            }
            mUp.segment<3>(3 * contact) = start + (s + 1.0) / mSubsteps * (target - start);
            mU.swap(mUp);
        }
        return -mF[3 * contact + 2];
    }

  private:
    const Problem& mP;
    Eigen::VectorXd mU, mUp, mF;
    int mSubsteps = 1;
};

struct SlideRun {
    std::vector<double> force, reference;
    std::vector<int> contact;  // driven node per tick
    int requests = 0, adopted = 0, maxDelay = 0;
    double maxPrimaryCheck = 0.0;
};

/// The contact moves one node along +x every @p moveTicks ticks (from n/2 - 2 towards the
/// edge); AsyncRegions synchronous, the whole mesh switching at the tick the regions do.
SlideRun slide(const Problem& p, AsyncRegionsOptions o, int moveTicks, int ticks,
               bool withReference) {
    int x = p.n / 2 - 2;
    AsyncRegions a(p.model, p.constraints, {p.top(x)}, o);
    MovingWholeMesh ref(p);
    SlideRun r;
    int driven = p.top(x), requestTick = 0;
    bool pending = false;
    for (int t = 1; t <= ticks; ++t) {
        if (t % moveTicks == 0 && x + 1 < p.n - 1) {
            ++x;
            EXPECT_TRUE(a.requestContactNode(p.top(x)));
            ++r.requests;
            requestTick = t;
            pending = true;
        }
        const double z = press(t * kTick);
        const AsyncTickResult res = a.tick(Eigen::Vector3d(0, 0, z));
        r.force.push_back(-res.contactForce.z());
        r.contact.push_back(driven);
        if (withReference) r.reference.push_back(ref.tick(driven, z));
        if (res.layoutChanged) {
            // Adopted at the end of this tick: the new node is driven from the next one.
            ++r.adopted;
            r.maxDelay = std::max(r.maxDelay, t - requestTick + 1);
            pending = false;
            driven = a.contactNodes()[0];
            const auto& prim = a.primaryNodes();
            EXPECT_TRUE(std::binary_search(prim.begin(), prim.end(), driven));
        }
    }
    if (pending) --r.requests;  // asked in the last period
    return r;
}

TEST(AsyncSliding, CapacitanceSecondaryEqualsAFactorisationPerLayout) {
    // The capacitance identity is exact: the one factor of the whole body with the primary
    // removed through J gives the forces of a layout assembled and factorised on its own.
    for (int lod : {1, 2}) {
        const Problem p(lod == 1 ? 11 : 13, 10.0);
        AsyncRegionsOptions o;
        o.lod = lod;
        o.primaryNodes = 12;
        o.secondaryRate = 100.0;
        const SlideRun global = slide(p, o, 60, 500, false);
        o.globalSecondary = false;
        const SlideRun own = slide(p, o, 60, 500, false);
        ASSERT_EQ(global.adopted, own.adopted);
        EXPECT_GT(global.adopted, 5);
        double worst = 0.0;
        for (std::size_t k = 0; k < own.force.size(); ++k)
            worst = std::max(worst, std::abs(global.force[k] - own.force[k]));
        std::cout << "[ capacitance ] lod " << lod << ": max |F_global - F_own| " << worst
                  << " N of peak " << peak(own.force) << " N\n";
        EXPECT_LT(worst, 1e-8 * peak(own.force));
    }
}

TEST(AsyncSliding, SlidingContactIsFollowedAndMatchesTheWholeMesh) {
    // A node every 100 ms and every 50 ms (50-100 mm/s with 5 mm nodes): every request is
    // adopted within one secondary period, the driven node is always primary, and the force
    // follows the whole mesh stepped explicitly with the same switches. 400 seeds: the top
    // layers around the contact (the error falls with the primary, see below).
    const Problem p(17, 10.0);
    for (int moveTicks : {100, 50}) {
        AsyncRegionsOptions o;
        o.lod = 2;
        o.primaryNodes = 400;
        o.secondaryRate = 100.0;
        const int ticks = 1000;
        const SlideRun r = slide(p, o, moveTicks, ticks, true);
        const double peakErr = std::abs(peak(r.force) - peak(r.reference)) / peak(r.reference);
        const double rms = rmsError(r.force, r.reference);
        std::cout << "[ sliding ] a node every " << moveTicks << " ms: " << r.adopted << " of "
                  << r.requests << " adopted, max delay " << r.maxDelay << " ticks; peak "
                  << peak(r.force) << " N vs " << peak(r.reference) << " N (" << 100.0 * peakErr
                  << " %), rms error " << 100.0 * rms << " %\n";
        EXPECT_EQ(r.adopted, r.requests);
        EXPECT_LE(r.maxDelay, 10);
        EXPECT_LT(peakErr, 0.05);
        // Each switch jerks the new node to the target within a tick; the ringing that follows
        // differs most (the quasi-static far field does not radiate), so the RMS error is
        // larger than the peak error and falls with the primary (17^3: 48 % RMS at 5 seeds,
        // 23 % at 30, 12 % at 120, 5-7 % at 400).
        EXPECT_LT(rms, 0.08);
    }
}

}  // namespace
}  // namespace palp::fem
