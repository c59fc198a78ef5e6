// Asynchronous FEM regions (issue 6): thesis table 3.1 (N primary nodes, f secondary rate, time
// per tick, gain over the whole solution, peak force, force error) against the whole fine mesh
// solved every tick on the same input in the same run; the interpolation switch; the adaptive
// primary on a growing sinusoid; level of detail; and a threaded real-time run with the servo
// thread and the secondary pinned to different cores.
//
// force: the force drive (deformable palpation): a raised-cosine force of --force N at the
// contact node, the whole mesh stepped explicitly every tick as the reference; per secondary
// rate a synchronous and a threaded (servo pinned to CPU 0 at 1 kHz wall clock, secondary on
// CPU 1) run with the top face watched (--watch 0: none; then the Gamma-only direct solve).
//
// Usage: bench_async [table|interp|growing|lod|threaded|force] [--size N] [--seconds S]
//        [--amplitude M] [--frequency HZ] [--lod L] [--solver cholmod|pcg] [--n LIST]
//        [--f LIST] [--integrator newmark|static] [--coupling plain|condensed]
//        [--once-per-tick 0|1] [--full-field 0|1] [--move MS] [--force N] [--watch 0|1]
//        [--global 0|1] [--sync 0|1] [--zone-max DOFS]
// --move MS (threaded): every MS milliseconds the contact moves one node along +x across the
// top face (re-allocation prepared on the secondary thread, adopted by the tick); the
// whole-mesh reference moves its contact at the same request ticks (movingReference).
// --global 0: factorise every layout instead of the capacitance secondary; --sync 1: run the
// threaded mode's loop with the secondary inline (synchronous mode, same moves).
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <numbers>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include "palp/base/thread.h"
#include "palp/fem/async_regions.h"
#include "palp/fem/explicit_solver.h"

namespace {

using namespace palp::fem;
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
    bool oncePerTick = false;
    bool fullField = false;
    int moveMs = 0;
    bool global = true;   // --global: the capacitance secondary (one factorisation)
    bool sync = false;    // --sync 1: the "threaded" run with the secondary inline (deterministic)
    int zoneMax = 3000;   // --zone-max: slideZoneMaxDofs
    double force = 0.05;  // newtons, force mode
    bool watch = true;    // force mode: watch the top face
    std::vector<int> nodes{5, 30, 120};
    std::vector<double> rates{50, 500, 1000};
    double alpha = 10.0;  // mass-proportional damping, 1/s
};

std::vector<double> parseList(const std::string& s) {
    std::vector<double> out;
    std::stringstream in(s);
    std::string item;
    while (std::getline(in, item, ',')) out.push_back(std::stod(item));
    return out;
}

ElasticMaterial tissue(double alpha) { return ElasticMaterial{5e3, 0.45, 1e3, alpha, 0.0}; }

/// Contact displacement along -z: a raised-cosine sinusoid starting at rest; "growing" scales
/// its amplitude linearly from 0 to the full amplitude over the run.
double inputAt(const Config& c, double t, bool growing) {
    const double a = growing ? c.amplitude * t / c.seconds : c.amplitude;
    return -a * 0.5 * (1.0 - std::cos(2.0 * std::numbers::pi * c.frequency * t));
}

struct Run {
    std::vector<double> force;  // z reaction per tick, N (pushing in gives +)
    std::vector<double> tickSeconds;
    double solveSeconds = 0.0;
    int primaryNodes = 0;
};

double peak(const std::vector<double>& f) {
    double p = 0.0;
    for (double v : f) p = std::max(p, std::abs(v));
    return p;
}

double percentile(std::vector<double> v, double q) {
    if (v.empty()) return 0.0;
    std::sort(v.begin(), v.end());
    return v[std::min(v.size() - 1, static_cast<std::size_t>(q * static_cast<double>(v.size())))];
}

double mean(const std::vector<double>& v) {
    double s = 0.0;
    for (double x : v) s += x;
    return v.empty() ? 0.0 : s / static_cast<double>(v.size());
}

/// Largest |F(k) - 2 F(k-1) + F(k-2)|: the force step that a sudden change adds on top of the
/// smooth sinusoid.
double maxJump(const std::vector<double>& f) {
    double j = 0.0;
    for (std::size_t k = 2; k < f.size(); ++k)
        j = std::max(j, std::abs(f[k] - 2 * f[k - 1] + f[k - 2]));
    return j;
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

Run reference(const Config& c, const Problem& p, bool growing) {
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

Run asyncRun(const Config& c, const Problem& p, AsyncRegionsOptions o, bool growing) {
    o.lod = c.lod;
    o.secondarySolver = c.solver;
    o.secondaryIntegrator = c.integrator;
    o.condensed = c.condensed;
    o.condensedOncePerTick = c.oncePerTick;
    o.secondaryFullField = c.fullField;
    AsyncRegions a(p.model, p.constraints, {p.contact}, o);
    Run r;
    r.primaryNodes = a.primaryFreeNodeCount();
    const int ticks = static_cast<int>(std::lround(c.seconds / 1e-3));
    for (int t = 1; t <= ticks; ++t) {
        const auto b = Clock::now();
        const AsyncTickResult res = a.tick(Eigen::Vector3d(0, 0, inputAt(c, t * 1e-3, growing)));
        const double dt = std::chrono::duration<double>(Clock::now() - b).count();
        // Synchronous mode: the inline secondary solve is booked as solve time, the rest as tick.
        if (res.secondaryUpdated) {
            const double solve = a.secondaryStats().lastSolveSeconds;
            r.solveSeconds += solve;
            r.tickSeconds.push_back(std::max(0.0, dt - solve));
        } else {
            r.tickSeconds.push_back(dt);
        }
        r.force.push_back(-res.contactForce.z());
    }
    if (o.maxPrimaryNodes > 0) r.primaryNodes = a.primaryFreeNodeCount();
    return r;
}

double relErr(double a, double b) { return std::abs(a - b) / std::abs(b); }

/// RMS of the force difference over the RMS of the reference force.
double rmsErr(const std::vector<double>& a, const std::vector<double>& ref) {
    double num = 0.0, den = 0.0;
    for (std::size_t k = 0; k < ref.size(); ++k) {
        num += (a[k] - ref[k]) * (a[k] - ref[k]);
        den += ref[k] * ref[k];
    }
    return std::sqrt(num / den);
}

void table(const Config& c) {
    const Problem p(c);
    const Run ref = reference(c, p, false);
    const double refTick = mean(ref.tickSeconds);
    std::printf(
        "cube %d^3 (%d dofs), h 5 mm, E 5 kPa, nu 0.45, alpha %.0f/s; input: contact node "
        "pressed %.1f mm, raised cosine %.1f Hz, %.1f s; lod %d, %s, %s, %s coupling\n",
        c.size, p.model.dofCount(), c.alpha, c.amplitude * 1e3, c.frequency, c.seconds, c.lod,
        c.solver == LinearSolverKind::cholmod ? "CHOLMOD" : "PCG",
        c.integrator == Integrator::newmark ? "Newmark" : "quasi-static",
        c.condensed ? "condensed" : "plain");
    std::printf("%-24s %6s %10s %10s %8s %12s %10s %8s %8s\n", "", "N", "f (Hz)", "tick (ms)",
                "gain", "solve (ms)", "peak (N)", "error", "rms err");
    std::printf("%-24s %6d %10s %10.4f %8s %12s %10.4f %8s %8s\n", "whole solution",
                ref.primaryNodes, "-", refTick * 1e3, "-", "-", peak(ref.force), "-", "-");
    for (int n : c.nodes) {
        for (double f : c.rates) {
            AsyncRegionsOptions o;
            o.primaryNodes = n;
            o.secondaryRate = f;
            const Run r = asyncRun(c, p, o, false);
            const double tick = mean(r.tickSeconds);
            const double solves = std::max(1.0, c.seconds * f);
            if (!(peak(r.force) < 100.0 * peak(ref.force))) {
                std::printf("%-24s %6d %10.0f %10.4f   diverged (peak %.3g N)\n", "asynchronous",
                            r.primaryNodes, f, tick * 1e3, peak(r.force));
                continue;
            }
            std::printf("%-24s %6d %10.0f %10.4f %7.1f%% %12.3f %10.4f %7.1f%% %7.1f%%\n",
                        "asynchronous", r.primaryNodes, f, tick * 1e3,
                        100.0 * (1.0 - tick / refTick), r.solveSeconds / solves * 1e3,
                        peak(r.force), 100.0 * relErr(peak(r.force), peak(ref.force)),
                        100.0 * rmsErr(r.force, ref.force));
        }
    }
}

void interp(const Config& c) {
    const Problem p(c);
    const Run ref = reference(c, p, false);
    std::printf(
        "interpolation switch, cube %d^3, lod %d: largest force step |F(k)-2F(k-1)+F(k-2)| "
        "(reference %.3g N)\n",
        c.size, c.lod, maxJump(ref.force));
    std::printf("%6s %8s %14s %14s %8s %10s %10s\n", "N", "f (Hz)", "step on (N)", "step off (N)",
                "ratio", "err on", "err off");
    for (int n : c.nodes) {
        for (double f : c.rates) {
            AsyncRegionsOptions o;
            o.primaryNodes = n;
            o.secondaryRate = f;
            o.condensed = false;
            const Run on = asyncRun(c, p, o, false);
            o.interpolate = false;
            const Run off = asyncRun(c, p, o, false);
            std::printf("%6d %8.0f %14.4g %14.4g %7.1fx %9.1f%% %9.1f%%\n", on.primaryNodes, f,
                        maxJump(on.force), maxJump(off.force),
                        maxJump(off.force) / maxJump(on.force),
                        100.0 * relErr(peak(on.force), peak(ref.force)),
                        100.0 * relErr(peak(off.force), peak(ref.force)));
        }
    }
}

void growing(const Config& c) {
    const Problem p(c);
    const Run ref = reference(c, p, true);
    std::printf(
        "growing-amplitude sinusoid (0 to %.1f mm over %.1f s, %.1f Hz), cube %d^3, lod "
        "%d; reference peak %.4f N\n",
        c.amplitude * 1e3, c.seconds, c.frequency, c.size, c.lod, peak(ref.force));
    std::printf("%-30s %8s %10s %8s %8s %10s\n", "primary", "f (Hz)", "peak (N)", "error",
                "rms err", "tick (ms)");
    for (double f : c.rates) {
        for (int variant = 0; variant < 3; ++variant) {
            AsyncRegionsOptions o;
            o.secondaryRate = f;
            o.primaryNodes = c.nodes.front();
            std::string name = "fixed N seeds " + std::to_string(c.nodes.front());
            if (variant == 1) {
                o.primaryNodes = c.nodes.back();
                name = "fixed N seeds " + std::to_string(c.nodes.back());
            } else if (variant == 2) {
                o.maxPrimaryNodes = c.nodes.back();
                o.strainAtMax = c.amplitude / o.strainReferenceLength;
                name = "adaptive seeds " + std::to_string(c.nodes.front()) + ".." +
                       std::to_string(c.nodes.back());
            }
            const Run r = asyncRun(c, p, o, true);
            std::printf("%-30s %8.0f %10.4f %7.2f%% %7.2f%% %10.4f\n", name.c_str(), f,
                        peak(r.force), 100.0 * relErr(peak(r.force), peak(ref.force)),
                        100.0 * rmsErr(r.force, ref.force), mean(r.tickSeconds) * 1e3);
        }
    }
}

void lod(const Config& c) {
    const Problem p(c);
    const Run ref = reference(c, p, false);
    std::printf("level of detail, cube %d^3, reference peak %.4f N, reference tick %.3f ms\n",
                c.size, peak(ref.force), mean(ref.tickSeconds) * 1e3);
    std::printf("%4s %6s %8s %10s %10s %8s %8s %12s %10s\n", "lod", "N", "f (Hz)", "tick (ms)",
                "peak (N)", "error", "rms err", "solve (ms)", "vs lod 1");
    for (double f : c.rates) {
        double peak1 = 0.0;
        for (int l : {1, 2, 4}) {
            Config cl = c;
            cl.lod = l;
            AsyncRegionsOptions o;
            o.primaryNodes = c.nodes.front();
            o.secondaryRate = f;
            const auto b = Clock::now();
            const Run r = asyncRun(cl, p, o, false);
            (void)b;
            if (l == 1) peak1 = peak(r.force);
            std::printf("%4d %6d %8.0f %10.4f %10.4f %7.2f%% %7.2f%% %12.3f %9.2f%%\n", l,
                        r.primaryNodes, f, mean(r.tickSeconds) * 1e3, peak(r.force),
                        100.0 * relErr(peak(r.force), peak(ref.force)),
                        100.0 * rmsErr(r.force, ref.force),
                        r.solveSeconds / std::max(1.0, c.seconds * f) * 1e3,
                        100.0 * relErr(peak(r.force), peak1));
        }
    }
}

/// The contact node of a moving-contact run at tick @p t (1-based): every moveMs ticks it moves
/// one node along +x across the top face (wrapping to x = 1), as threaded() requests it.
int movingContactAt(const Config& c, const Problem& p, int t) {
    if (c.moveMs <= 0) return p.contact;
    int x = c.size / 2;
    for (int k = c.moveMs; k <= t; k += c.moveMs) x = x + 1 < c.size - 1 ? x + 1 : 1;
    return p.model.mesh().node(x, c.size / 2, c.size - 1);
}

/// Whole-mesh reference that follows the moving contact with the switch semantics of
/// AsyncRegions, at the request tick: the old contact node is released with its displacement
/// and velocity, the new one moves from its displacement to the tick's target within the tick.
/// The central difference of ExplicitSolver (lumped mass, mass-proportional damping; the bench
/// material has no stiffness damping), whose constraints are fixed at construction.
Run movingReference(const Config& c, const Problem& p) {
    const FemModel& m = p.model;
    const int dofs = m.dofCount();
    const Eigen::VectorXd& mass = m.lumpedMass();
    const double critical = 0.9 * m.criticalTimeStep();
    const int substeps = std::max(1, static_cast<int>(std::ceil(1e-3 / critical)));
    const double dt = 1e-3 / substeps, alpha = m.material().dampingAlpha;
    std::vector<char> fixed(static_cast<std::size_t>(dofs), 0);
    for (int d = 0; d < dofs; ++d) fixed[static_cast<std::size_t>(d)] = p.constraints.isFixed(d);
    Eigen::VectorXd u = Eigen::VectorXd::Zero(dofs), up = u, f = u;
    Run r;
    const int ticks = static_cast<int>(std::lround(c.seconds / 1e-3));
    for (int t = 1; t <= ticks; ++t) {
        const int contact = movingContactAt(c, p, t);
        const Eigen::Vector3d start = u.segment<3>(3 * contact);
        const Eigen::Vector3d target(0, 0, inputAt(c, t * 1e-3, false));
        for (int s = 0; s < substeps; ++s) {
            f.setZero();
            m.addStiffnessTimes(u.data(), f.data());
            for (int d = 0; d < dofs; ++d) {
                if (fixed[static_cast<std::size_t>(d)] || mass[d] <= 0.0) continue;
                up[d] = (-dt * dt * f[d] + 2.0 * mass[d] * u[d] -
                         (1.0 - 0.5 * dt * alpha) * mass[d] * up[d]) /
                        ((1.0 + 0.5 * dt * alpha) * mass[d]);
            }
            up.segment<3>(3 * contact) = start + (s + 1.0) / substeps * (target - start);
            u.swap(up);
        }
        r.force.push_back(-f[3 * contact + 2]);
    }
    return r;
}

/// Threaded: the servo thread pinned to CPU 0 ticks at 1 kHz wall clock (sleeping to the next
/// deadline), the secondary pinned to CPU 1.
void threaded(const Config& c) {
    const Problem p(c);
    const Run ref = c.moveMs > 0 ? movingReference(c, p) : reference(c, p, false);
    palp::pinCurrentThread(0);  // best effort, as before: a refused pin only changes timings
    for (double f : c.rates) {
        AsyncRegionsOptions o;
        o.primaryNodes = c.nodes.front();
        o.secondaryRate = f;
        o.lod = c.lod;
        o.secondarySolver = c.solver;
        o.secondaryIntegrator = c.integrator;
        o.condensed = c.condensed;
        o.condensedOncePerTick = c.oncePerTick;
        o.secondaryFullField = c.fullField;
        o.threaded = !c.sync;
        o.globalSecondary = c.global;
        o.slideZoneMaxDofs = c.zoneMax;
        o.secondaryCpu = 1;
        AsyncRegions a(p.model, p.constraints, {p.contact}, o);
        const int ticks = static_cast<int>(std::lround(c.seconds / 1e-3));
        std::vector<double> tickTimes, force, swapTicks;
        int overruns = 0, moves = 0, adopted = 0, requestTick = 0, maxDelay = 0;
        const int y = c.size / 2, z = c.size - 1;
        int x = c.size / 2;
        const auto start = Clock::now();
        auto deadline = start;
        for (int t = 1; t <= ticks; ++t) {
            if (c.moveMs > 0 && t % c.moveMs == 0) {
                x = x + 1 < c.size - 1 ? x + 1 : 1;
                a.requestContactNode(p.model.mesh().node(x, y, z));
                ++moves;
                requestTick = t;
            }
            const auto b = Clock::now();
            const AsyncTickResult res = a.tick(Eigen::Vector3d(0, 0, inputAt(c, t * 1e-3, false)));
            const auto e = Clock::now();
            tickTimes.push_back(std::chrono::duration<double>(e - b).count());
            if (res.layoutChanged) {
                ++adopted;
                swapTicks.push_back(tickTimes.back());
                maxDelay = std::max(maxDelay, t - requestTick);
            }
            force.push_back(-res.contactForce.z());
            deadline += std::chrono::microseconds(1000);
            if (e > deadline) {
                ++overruns;
            } else {
                std::this_thread::sleep_until(deadline);
            }
        }
        const double wall = std::chrono::duration<double>(Clock::now() - start).count();
        const AsyncSecondaryStats s = a.secondaryStats();
        std::printf(
            "threaded %d^3 lod %d %s%s N %d f %.0f Hz (%d substeps): tick mean %.4f ms, p99 %.4f "
            "ms, max "
            "%.4f ms, overruns %d; secondary %llu solves in %.2f s (%.1f Hz, wanted %.0f), "
            "last solve %.2f ms (CPU %.2f ms), max %.2f ms, %llu used; peak %.4f N vs reference "
            "%.4f N "
            "(%.2f%%), rms err %.2f%%\n",
            c.size, c.lod, c.solver == LinearSolverKind::cholmod ? "CHOLMOD" : "PCG",
            c.fullField ? " full field" : "", a.primaryFreeNodeCount(), f,
            static_cast<int>(std::lround(1e-3 / a.substepSeconds())), mean(tickTimes) * 1e3,
            percentile(tickTimes, 0.99) * 1e3, percentile(tickTimes, 1.0) * 1e3, overruns,
            static_cast<unsigned long long>(s.solves), wall, static_cast<double>(s.solves) / wall,
            f, s.lastSolveSeconds * 1e3, s.lastSolveCpuSeconds * 1e3, s.maxSolveSeconds * 1e3,
            static_cast<unsigned long long>(s.used), peak(force), peak(ref.force),
            100.0 * relErr(peak(force), peak(ref.force)), 100.0 * rmsErr(force, ref.force));
        if (c.moveMs > 0) {
            std::printf(
                "  moving contact: %d requests, %d layouts adopted, last preparation %.1f ms "
                "(secondary thread), swap ticks max %.4f ms, force finite %s, max |F| %.4f N; "
                "adopted %.0f%%, request to adoption max %d ticks; reference follows the moves\n",
                moves, adopted, s.lastPrepareSeconds * 1e3, percentile(swapTicks, 1.0) * 1e3,
                std::all_of(force.begin(), force.end(), [](double v) { return std::isfinite(v); })
                    ? "yes"
                    : "no",
                peak(force), 100.0 * adopted / std::max(1, moves), maxDelay);
        }
    }
}

/// Force drive: contact displacement and watched top-face displacement against the whole mesh
/// stepped explicitly under the same force.
void forceDrive(const Config& c) {
    const Problem p(c);
    const int ticks = static_cast<int>(std::lround(c.seconds / 1e-3));
    auto forceAt = [&](int t) {
        return -c.force * 0.5 * (1.0 - std::cos(2.0 * std::numbers::pi * c.frequency * t * 1e-3));
    };
    // The error over the top face is taken at the tick of the largest reference displacement.
    std::vector<int> watch = p.model.mesh().faceNodes(BoxFace::zMax);
    std::vector<double> ref;
    double refTick = 0.0;
    int peakTick = 1;
    std::vector<Eigen::Vector3d> refSurface(watch.size());
    {
        ExplicitSolver s(p.model, p.constraints);
        std::vector<double> times;
        double best = -1.0;
        for (int t = 1; t <= ticks; ++t) {
            s.externalForce()[3 * p.contact + 2] = forceAt(t);
            const auto b = Clock::now();
            s.step(1e-3);
            times.push_back(std::chrono::duration<double>(Clock::now() - b).count());
            const double z = s.displacement()[3 * p.contact + 2];
            ref.push_back(z);
            if (std::abs(z) > best) {
                best = std::abs(z);
                peakTick = t;
                for (std::size_t i = 0; i < watch.size(); ++i)
                    refSurface[i] = s.displacement().segment<3>(3 * watch[i]);
            }
        }
        refTick = mean(times);
    }
    double refSurfaceMax = 0.0;
    for (const auto& v : refSurface) refSurfaceMax = std::max(refSurfaceMax, v.norm());
    std::printf(
        "force drive, cube %d^3 (%d dofs), alpha %.0f/s: %.3f N raised cosine %.1f Hz at the top "
        "centre, %.1f s; lod %d, %s, %s coupling, %zu watched nodes; whole mesh explicit: tick "
        "%.3f ms, peak %.4f mm at tick %d\n",
        c.size, p.model.dofCount(), c.alpha, c.force, c.frequency, c.seconds, c.lod,
        c.solver == LinearSolverKind::cholmod ? "CHOLMOD" : "PCG",
        c.condensed ? "condensed" : "plain", c.watch ? watch.size() : std::size_t{0}, refTick * 1e3,
        peak(ref) * 1e3, peakTick);
    std::printf("%-9s %5s %6s %9s %9s %9s %8s %9s %9s %10s %9s %8s %8s %9s\n", "mode", "N", "f",
                "tick ms", "p99 ms", "max ms", "overrun", "sec Hz", "solve ms", "solve CPU",
                "peak mm", "error", "rms err", "surf err");
    palp::pinCurrentThread(0);  // best effort, as before: a refused pin only changes timings
    for (double f : c.rates) {
        for (bool threadedRun : {false, true}) {
            AsyncRegionsOptions o;
            o.drive = ContactDrive::force;
            o.primaryNodes = c.nodes.front();
            o.secondaryRate = f;
            o.lod = c.lod;
            o.secondarySolver = c.solver;
            o.secondaryIntegrator = Integrator::quasiStatic;
            o.condensed = c.condensed;
            o.condensedOncePerTick = c.oncePerTick;
            o.secondaryFullField = c.fullField;
            if (c.watch) o.watchNodes = watch;
            o.threaded = threadedRun;
            o.secondaryCpu = threadedRun ? 1 : -1;
            AsyncRegions a(p.model, p.constraints, {p.contact}, o);
            std::vector<Eigen::Vector3d> w(o.watchNodes.size());
            std::vector<double> z, tickTimes;
            double surfErr = 0.0;
            int overruns = 0;
            const auto start = Clock::now();
            auto deadline = start;
            for (int t = 1; t <= ticks; ++t) {
                const NodalLoad load{p.contact, {0, 0, forceAt(t)}};
                const auto b = Clock::now();
                const AsyncTickResult r = a.tick(std::span<const NodalLoad>(&load, 1));
                a.watchedDisplacements(w);
                const auto e = Clock::now();
                double dt = std::chrono::duration<double>(e - b).count();
                if (!threadedRun && r.secondaryUpdated) {  // inline solve: booked apart
                    dt = std::max(0.0, dt - a.secondaryStats().lastSolveSeconds);
                }
                tickTimes.push_back(dt);
                z.push_back(r.contactDisplacement.z());
                if (t == peakTick && !w.empty()) {
                    for (std::size_t i = 0; i < w.size(); ++i)
                        surfErr = std::max(surfErr, (w[i] - refSurface[i]).norm());
                }
                if (threadedRun) {
                    deadline += std::chrono::microseconds(1000);
                    if (e > deadline) {
                        ++overruns;
                    } else {
                        std::this_thread::sleep_until(deadline);
                    }
                }
            }
            const double wall = std::chrono::duration<double>(Clock::now() - start).count();
            const AsyncSecondaryStats st = a.secondaryStats();
            const double rate =
                threadedRun ? static_cast<double>(st.solves) / wall : 1e3 / a.periodTicks();
            std::printf(
                "%-9s %5d %6.0f %9.4f %9.4f %9.4f %8d %9.1f %9.3f %10.3f %9.4f %7.2f%% %7.2f%% "
                "%8.2f%%\n",
                threadedRun ? "threaded" : "sync", a.primaryFreeNodeCount(), f,
                mean(tickTimes) * 1e3, percentile(tickTimes, 0.99) * 1e3,
                percentile(tickTimes, 1.0) * 1e3, overruns, rate, st.lastSolveSeconds * 1e3,
                st.lastSolveCpuSeconds * 1e3, peak(z) * 1e3, 100.0 * relErr(peak(z), peak(ref)),
                100.0 * rmsErr(z, ref), w.empty() ? 0.0 : 100.0 * surfErr / refSurfaceMax);
        }
    }
}

}  // namespace

int main(int argc, char** argv) {
    Config c;
    int i = 1;
    if (argc > 1 && argv[1][0] != '-') c.mode = argv[i++];
    for (; i + 1 < argc; i += 2) {
        const std::string k = argv[i], v = argv[i + 1];
        if (k == "--size") {
            c.size = std::stoi(v);
        } else if (k == "--seconds") {
            c.seconds = std::stod(v);
        } else if (k == "--amplitude") {
            c.amplitude = std::stod(v);
        } else if (k == "--frequency") {
            c.frequency = std::stod(v);
        } else if (k == "--lod") {
            c.lod = std::stoi(v);
        } else if (k == "--alpha") {
            c.alpha = std::stod(v);
        } else if (k == "--solver") {
            c.solver = v == "pcg" ? LinearSolverKind::pcg : LinearSolverKind::cholmod;
        } else if (k == "--integrator") {
            c.integrator = v == "static" ? Integrator::quasiStatic : Integrator::newmark;
        } else if (k == "--once-per-tick") {
            c.oncePerTick = v != "0";
        } else if (k == "--full-field") {
            c.fullField = v != "0";
        } else if (k == "--force") {
            c.force = std::stod(v);
        } else if (k == "--watch") {
            c.watch = v != "0";
        } else if (k == "--move") {
            c.moveMs = std::stoi(v);
        } else if (k == "--global") {
            c.global = std::stoi(v) != 0;
        } else if (k == "--sync") {
            c.sync = std::stoi(v) != 0;
        } else if (k == "--zone-max") {
            c.zoneMax = std::stoi(v);
        } else if (k == "--coupling") {
            c.condensed = v != "plain";
        } else if (k == "--n") {
            c.nodes.clear();
            for (double x : parseList(v)) c.nodes.push_back(static_cast<int>(x));
        } else if (k == "--f") {
            c.rates = parseList(v);
        } else {
            std::fprintf(stderr, "bench_async: unknown option %s\n", k.c_str());
            return 2;
        }
    }
    if (c.mode == "table") {
        table(c);
    } else if (c.mode == "interp") {
        interp(c);
    } else if (c.mode == "growing") {
        growing(c);
    } else if (c.mode == "lod") {
        lod(c);
    } else if (c.mode == "threaded") {
        threaded(c);
    } else if (c.mode == "force") {
        forceDrive(c);
    } else {
        std::fprintf(stderr, "bench_async: unknown mode %s\n", c.mode.c_str());
        return 2;
    }
    return 0;
}
