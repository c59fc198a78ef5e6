#pragma once
// The problem both halves of bench_async share (bench_async.cpp: the thesis's tables and the
// force drive; bench_async_slide.cpp: the threaded run and the moving contact): options, the cube
// problem, the input and the error measures. It includes neither half.
#include <algorithm>
#include <chrono>
#include <cmath>
#include <numbers>
#include <sstream>
#include <string>
#include <vector>

#include "palp/fem/async_regions.h"
#include "palp/fem/explicit_solver.h"

namespace palp::fem::bench {

using Clock = std::chrono::steady_clock;

struct Config {
    std::string mode = "table";
    int size = 13;
    double seconds = 1.0;
    double amplitude = 0.003;  // metres
    double frequency = 1.0;    // Hz
    int lod = 1;
    LinearSolverKind solver = LinearSolverKind::cholmod;
    Integrator integrator = Integrator::quasiStatic;
    bool condensed = true;
    double lead = 0.5;  // --plain-lead: plainLead (negative: the thesis's interpolation)
    bool oncePerTick = false;
    bool fullField = false;
    int moveMs = 0;
    bool global = true;   // --global: the capacitance secondary (one factorisation)
    bool sync = false;    // --sync 1: the "threaded" run with the secondary inline (deterministic)
    int zoneMax = 3000;   // --zone-max: slideZoneMaxDofs
    double force = 0.05;  // newtons, force mode
    bool watch = true;    // force mode: watch the top face
    std::vector<int> nodes{5, 30, 120};
    bool nodesGiven = false;  // --n given (threaded slide: else the library's default primary)
    std::vector<double> rates{50, 500, 1000};
    double alpha = 10.0;  // mass-proportional damping, 1/s
    // Moving contact (threaded --move): "slide" (default) a finger sliding continuously through
    // a coupling spring, "jump" the driven node jumping one node at each move (worse case).
    std::string contact = "slide";
    double filterMm = 3.0;      // slide: Gaussian contact filter sigma, mm (0: linear, 2 nodes)
    double stiffness = 1000;    // slide: coupling spring k, N/m
    double dampingRatio = 1.0;  // slide: contact damper, fraction of critical (as DeformableBody)
    double leadMs = 25.0;       // slide: request the node nearest the point this far ahead
};

inline std::vector<double> parseList(const std::string& s) {
    std::vector<double> out;
    std::stringstream in(s);
    std::string item;
    while (std::getline(in, item, ',')) out.push_back(std::stod(item));
    return out;
}

inline ElasticMaterial tissue(double alpha) { return ElasticMaterial{5e3, 0.45, 1e3, alpha, 0.0}; }

/// Contact displacement along -z: a raised-cosine sinusoid starting at rest; "growing" scales
/// its amplitude linearly from 0 to the full amplitude over the run.
inline double inputAt(const Config& c, double t, bool growing) {
    const double a = growing ? c.amplitude * t / c.seconds : c.amplitude;
    return -a * 0.5 * (1.0 - std::cos(2.0 * std::numbers::pi * c.frequency * t));
}

struct Run {
    std::vector<double> force;  // z reaction per tick, N (pushing in gives +)
    std::vector<double> tickSeconds;
    double solveSeconds = 0.0;
    int primaryNodes = 0;
};

inline double peak(const std::vector<double>& f) {
    double p = 0.0;
    for (double v : f) p = std::max(p, std::abs(v));
    return p;
}

inline double percentile(std::vector<double> v, double q) {
    if (v.empty()) return 0.0;
    std::sort(v.begin(), v.end());
    return v[std::min(v.size() - 1, static_cast<std::size_t>(q * static_cast<double>(v.size())))];
}

inline double mean(const std::vector<double>& v) {
    double s = 0.0;
    for (double x : v) s += x;
    return v.empty() ? 0.0 : s / static_cast<double>(v.size());
}

struct Problem {
    FemModel model;
    Constraints constraints;
    int contact;
    explicit Problem(const Config& c)
        : model(HexMesh::box(Eigen::Vector3d::Constant(0.005 * (c.size - 1)),
                             {c.size, c.size, c.size}, 5e3),
                tissue(c.alpha)),
          constraints(model.dofCount()),
          contact(model.mesh().node(c.size / 2, c.size / 2, c.size - 1)) {
        constraints.fixNodes(model.mesh().faceNodes(BoxFace::zMin));
    }
};

/// The whole fine mesh stepped explicitly every tick with the contact node driven.
inline Run reference(const Config& c, const Problem& p, bool growing) {
    Constraints k = p.constraints;
    for (int d = 0; d < 3; ++d) k.prescribe(3 * p.contact + d, 0.0);
    ExplicitSolver s(p.model, k);
    Run r;
    const int ticks = static_cast<int>(std::lround(c.seconds / 1e-3));
    for (int t = 1; t <= ticks; ++t) {
        s.setPrescribed(3 * p.contact + 2, inputAt(c, t * 1e-3, growing));
        const auto b = Clock::now();
        s.step(1e-3);
        r.tickSeconds.push_back(std::chrono::duration<double>(Clock::now() - b).count());
        r.force.push_back(-s.reaction(3 * p.contact + 2));
    }
    r.primaryNodes = p.model.mesh().nodeCount();
    return r;
}

/// The secondary's options every run takes from the command line (lod, solver, integrator,
/// condensed coupling, the plain coupling's lead, full field).
inline void applySecondaryOptions(const Config& c, AsyncRegionsOptions& o) {
    o.lod = c.lod;
    o.secondarySolver = c.solver;
    o.secondaryIntegrator = c.integrator;
    o.condensed = c.condensed;
    o.plainLead = c.lead;
    o.condensedOncePerTick = c.oncePerTick;
    o.secondaryFullField = c.fullField;
}

inline double relErr(double a, double b) { return std::abs(a - b) / std::abs(b); }

/// RMS of the force difference over the RMS of the reference force.
inline double rmsErr(const std::vector<double>& a, const std::vector<double>& ref) {
    double num = 0.0, den = 0.0;
    for (std::size_t k = 0; k < ref.size(); ++k) {
        num += (a[k] - ref[k]) * (a[k] - ref[k]);
        den += ref[k] * ref[k];
    }
    return std::sqrt(num / den);
}

}  // namespace palp::fem::bench
