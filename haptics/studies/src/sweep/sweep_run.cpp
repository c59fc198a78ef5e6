// The sweep's runner: one sample is the asynchronous regions and the whole-mesh reference on the
// same input (sweep_run.h).
#include "palp/studies/sweep_run.h"

#include <tbb/task_arena.h>

#include <chrono>
#include <cmath>
#include <cstdio>
#include <numbers>

#include "palp/base/error.h"
#include "palp/fem/async_regions.h"
#include "palp/fem/explicit_solver.h"

namespace palp::haptics {

namespace run_impl {

using Clock = std::chrono::steady_clock;

double seconds(Clock::time_point since) {
    return std::chrono::duration<double>(Clock::now() - since).count();
}

constexpr double kTick = 1e-3;  // servo tick, s

double value(const std::array<double, kSweepVarCount>& x, SweepVar v) {
    return x[static_cast<std::size_t>(v)];
}

/// The cube of the ranges' mesh with the sample's material, fixed at its bottom face.
struct Problem {
    fem::FemModel model;
    fem::Constraints constraints;
    int contact;
    Problem(const SweepRanges& r, const std::array<double, kSweepVarCount>& x)
        : model(
              fem::HexMesh::box(Eigen::Vector3d::Constant(r.spacingM * (r.meshNodes - 1)),
                                {r.meshNodes, r.meshNodes, r.meshNodes},
                                value(x, SweepVar::youngs)),
              fem::ElasticMaterial{value(x, SweepVar::youngs), value(x, SweepVar::poisson),
                                   value(x, SweepVar::density), value(x, SweepVar::damping), 0.0}),
          constraints(model.dofCount()),
          contact(r.contactNodes().at(static_cast<std::size_t>(value(x, SweepVar::contact)))) {
        constraints.fixNodes(model.mesh().faceNodes(fem::BoxFace::zMin));
    }
};

int ticksOf(const SweepRanges& r) { return static_cast<int>(std::lround(r.durationS / kTick)); }

std::vector<double> referenceForce(const SweepRanges& r,
                                   const std::array<double, kSweepVarCount>& x) {
    const Problem p(r, x);
    fem::Constraints k = p.constraints;
    for (int d = 0; d < 3; ++d) k.prescribe(3 * p.contact + d, 0.0);
    fem::ExplicitOptions eo;
    eo.maxSubsteps = fem::kMaxExplicitSubsteps;
    fem::ExplicitSolver s(p.model, k, eo);
    std::vector<double> f;
    const int ticks = ticksOf(r);
    f.reserve(static_cast<std::size_t>(ticks));
    for (int t = 1; t <= ticks; ++t) {
        s.setPrescribed(3 * p.contact + 2, sweepInput(r, x, t * kTick));
        s.step(kTick);
        f.push_back(-s.reaction(3 * p.contact + 2));
    }
    return f;
}

}  // namespace run_impl

using namespace run_impl;

double sweepInput(const SweepRanges& r, const std::array<double, kSweepVarCount>& x, double t) {
    const double a = value(x, SweepVar::strain) * r.spacingM * (r.meshNodes - 1);
    return -a * 0.5 * (1.0 - std::cos(2.0 * std::numbers::pi * value(x, SweepVar::frequency) * t));
}

SweepRunner::SweepRunner(const SweepSpec& spec) : mSampler(spec) {}

SweepSampleResult SweepRunner::run(std::int64_t index) {
    SweepSampleResult out;
    out.index = index;
    out.x = mSampler.sample(index);
    // One core: TBB loops inside the FEM run in a one-thread arena (deterministic reductions,
    // and samples/s per core is what the sweep's cost is counted in).
    tbb::task_arena arena(1);
    try {
        arena.execute([&] { runIn(index, out); });
    } catch (const Error& e) {
        char what[160];
        std::snprintf(what, sizeof what,
                      "sweep sample %lld (lod %g, primary %g, rate %g Hz, coupling %g): ",
                      static_cast<long long>(index), value(out.x, SweepVar::lod),
                      value(out.x, SweepVar::primary), value(out.x, SweepVar::rate),
                      value(out.x, SweepVar::coupling));
        throw ValueError(what + std::string(e.what()));
    }
    return out;
}

void SweepRunner::runIn(std::int64_t index, SweepSampleResult& out) {
    const SweepSpec& spec = mSampler.spec();
    const SweepRanges& r = spec.ranges;
    {
        const std::int64_t group = index / spec.groupSize();
        if (group != mCachedGroup) {
            const auto b = Clock::now();
            // The group's first sample carries the group's input and material.
            mReference = referenceForce(r, mSampler.sample(group * spec.groupSize()));
            mCachedGroup = group;
            ++mReferences;
            out.referenceSeconds = seconds(b);
        }
        const auto b = Clock::now();
        const Problem p(r, out.x);
        out.contactNode = p.contact;
        fem::AsyncRegionsOptions o;
        o.threaded = false;
        o.tickSeconds = kTick;
        o.primaryNodes = static_cast<int>(value(out.x, SweepVar::primary));
        o.lod = static_cast<int>(value(out.x, SweepVar::lod));
        o.secondaryRate = value(out.x, SweepVar::rate);
        o.condensed = value(out.x, SweepVar::coupling) != 0.0;
        o.maxSubsteps = fem::kMaxExplicitSubsteps;
        // The contact does not move: factorise the one layout instead of inverting a slide zone.
        o.globalSecondary = false;
        fem::AsyncRegions regions(p.model, p.constraints, {p.contact}, o);
        out.primaryFreeNodes = regions.primaryFreeNodeCount();
        double num = 0.0, den = 0.0, peakA = 0.0, peakR = 0.0, maxDiff = 0.0;
        const int ticks = static_cast<int>(mReference.size());
        bool finite = true;
        for (int t = 1; t <= ticks; ++t) {
            const auto res = regions.tick(Eigen::Vector3d(0, 0, sweepInput(r, out.x, t * kTick)));
            const double fa = -res.contactForce.z(),
                         fr = mReference[static_cast<std::size_t>(t - 1)];
            finite = finite && std::isfinite(fa);
            num += (fa - fr) * (fa - fr);
            den += fr * fr;
            peakA = std::max(peakA, std::abs(fa));
            peakR = std::max(peakR, std::abs(fr));
            maxDiff = std::max(maxDiff, std::abs(fa - fr));
        }
        out.asyncSeconds = seconds(b);
        out.forceN = peakR;
        out.errPeak = std::abs(peakA - peakR) / peakR;
        out.errRms = std::sqrt(num / den);
        out.errMax = maxDiff / peakR;
        out.diverged = !finite || !(peakA < 100.0 * peakR);
        if (!finite)
            out.errPeak = out.errRms = out.errMax = std::numeric_limits<double>::infinity();
    }
}

const std::vector<SweepColumn>& sweepColumns() {
    static const std::vector<SweepColumn> cols = [] {
        std::vector<SweepColumn> c{{"sample", "1", "index", "sample index"}};
        for (int v = 0; v < kSweepVarCount; ++v)
            c.push_back(
                {sweepVarInfo(v).name, sweepVarInfo(v).unit, "variable", sweepVarInfo(v).label});
        c.push_back({"contact_node", "1", "derived", "fine node index driven"});
        c.push_back({"primary_free_nodes", "nodes", "derived",
                     "free nodes of the primary region (the thesis's N)"});
        c.push_back({"force", "N", "derived", "peak |reference contact force|"});
        c.push_back({"err_peak", "1", "response",
                     "|peak F_async - peak F_ref| / peak F_ref (relative error of the peak)"});
        c.push_back({"err_rms", "1", "response",
                     "rms(F_async - F_ref) / rms(F_ref) over the run (relative RMS error)"});
        c.push_back({"err_max", "1", "response", "max |F_async - F_ref| / peak F_ref"});
        c.push_back({"diverged", "1", "flag",
                     "1 when the regions' force was not finite or peaked over 100x the reference"});
        return c;
    }();
    return cols;
}

std::string sweepRow(const SweepSampleResult& r) {
    std::string s = std::to_string(r.index);
    char buf[40];
    auto add = [&](double v) {
        std::snprintf(buf, sizeof buf, ",%.9g", v);
        s += buf;
    };
    for (double v : r.x) add(v);
    // Appended piece by piece: GCC 12 at -O3 reports a false -Wrestrict overlap in
    // `"," + std::to_string(...)` when this file is compiled alone (not in a unity batch).
    s += ',';
    s += std::to_string(r.contactNode);
    s += ',';
    s += std::to_string(r.primaryFreeNodes);
    add(r.forceN);
    add(r.errPeak);
    add(r.errRms);
    add(r.errMax);
    s += r.diverged ? ",1" : ",0";
    return s;
}

}  // namespace palp::haptics
