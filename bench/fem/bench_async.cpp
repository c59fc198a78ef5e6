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
// stability: the plain coupling's period map (palp/fem/async_stability.h) per N and f, its
// spectral radius beside the run's peak error or divergence (--seconds 0: the analysis alone).
//
// Usage: bench_async [table|interp|growing|lod|threaded|force|stability] [--size N] [--seconds S]
//        [--amplitude M] [--frequency HZ] [--lod L] [--solver cholmod|pcg] [--n LIST]
//        [--f LIST] [--integrator newmark|euler|static] [--coupling plain|condensed]
//        [--plain-lead L]
//        [--once-per-tick 0|1] [--full-field 0|1] [--move MS] [--force N] [--watch 0|1]
//        [--global 0|1] [--sync 0|1] [--zone-max DOFS] [--contact slide|jump] [--filter-mm S]
//        [--k N/m] [--damping-ratio R] [--lead MS]
// --move MS (threaded, bench_async_slide.cpp): the contact moves one node (5 mm) every MS
// milliseconds, for 6 s unless --seconds is given. --contact slide (default): a finger sliding
// continuously at that speed through a coupling spring (filter sigma --filter-mm, stiffness
// --k, contact damper --damping-ratio), the regions asked for the node nearest the point --lead
// ms ahead, the top face watched as DeformableBody watches its surface (--watch 0: none); the
// whole mesh under the same spring is the reference. --contact jump: the driven node jumps one node
// along +x at each move (wrapping to x = 1), the whole-mesh reference switching at the same request
// ticks.
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

#include "async_problem.h"
#include "bench_async_slide.h"
#include "palp/base/thread.h"
#include "palp/fem/async_stability.h"
#include "palp/fem/explicit_solver.h"

namespace {

using namespace palp::fem;
using namespace palp::fem::bench;

/// Largest |F(k) - 2 F(k-1) + F(k-2)|: the force step that a sudden change adds on top of the
/// smooth sinusoid.
double maxJump(const std::vector<double>& f) {
    double j = 0.0;
    for (std::size_t k = 2; k < f.size(); ++k)
        j = std::max(j, std::abs(f[k] - 2 * f[k - 1] + f[k - 2]));
    return j;
}

const char* integratorName(Integrator i) {
    return i == Integrator::newmark         ? "Newmark"
           : i == Integrator::backwardEuler ? "backward Euler"
                                            : "quasi-static";
}

Run asyncRun(const Config& c, const Problem& p, AsyncRegionsOptions o, bool growing) {
    applySecondaryOptions(c, o);
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

void table(const Config& c) {
    const Problem p(c);
    const Run ref = reference(c, p, false);
    const double refTick = mean(ref.tickSeconds);
    std::printf(
        "cube %d^3 (%d dofs), h 5 mm, E 5 kPa, nu 0.45, alpha %.0f/s; input: contact node "
        "pressed %.1f mm, raised cosine %.1f Hz, %.1f s; lod %d, %s, %s, %s coupling\n",
        c.size, p.model.dofCount(), c.alpha, c.amplitude * 1e3, c.frequency, c.seconds, c.lod,
        c.solver == LinearSolverKind::cholmod ? "CHOLMOD" : "PCG", integratorName(c.integrator),
        c.condensed ? "condensed" : "plain");
    if (!c.condensed) std::printf("plain coupling's lead %.2f\n", c.lead);
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

/// The plain coupling's period map (async_stability.h): its spectral radius per N and f beside
/// the run's peak error (or its divergence) on the same problem.
void stability(const Config& c) {
    const Problem p(c);
    const bool runs = c.seconds > 0.0;  // --seconds 0: the analysis alone
    const Run ref = runs ? reference(c, p, false) : Run{};
    std::printf(
        "plain coupling (lead %.2f), cube %d^3, lod %d, %s secondary: spectral radius of the "
        "period map against the run\n",
        c.lead, c.size, c.lod, integratorName(c.integrator));
    std::printf("%6s %8s %7s %9s %7s %7s %6s %10s %18s %10s %10s %8s\n", "N", "f (Hz)", "ticks",
                "substeps", "free", "Gamma", "state", "rho", "dominant", "growth", "peak (N)",
                "error");
    for (int n : c.nodes) {
        for (double f : c.rates) {
            AsyncRegionsOptions o;
            o.primaryNodes = n;
            o.secondaryRate = f;
            applySecondaryOptions(c, o);
            const auto b = Clock::now();
            const StaggeredStability s = staggeredStability(p.model, p.constraints, {p.contact}, o);
            const double sec = std::chrono::duration<double>(Clock::now() - b).count();
            o.condensed = false;
            const Run r = runs ? asyncRun(c, p, o, false) : Run{{0.0}, {}, 0.0, n};
            const bool diverged = runs && !(peak(r.force) < 100.0 * peak(ref.force));
            std::printf(
                "%6d %8.0f %7d %9d %7d %7d %6d %10.4f %8.4f%+8.4fi %10.4f %10.3g %7.1f%%%s "
                "(%.2f s, %s)\n",
                r.primaryNodes, f, s.periodTicks, s.substeps, s.freeDofs, s.gammaDofs, s.stateSize,
                s.spectralRadius, s.dominant.real(), s.dominant.imag(), s.growthPerPeriod,
                peak(r.force), runs ? 100.0 * relErr(peak(r.force), peak(ref.force)) : 0.0,
                diverged ? " diverged" : "", sec, s.dense ? "dense" : "Arnoldi");
        }
    }
}

}  // namespace

int main(int argc, char** argv) {
    Config c;
    bool secondsGiven = false;
    int i = 1;
    if (argc > 1 && argv[1][0] != '-') c.mode = argv[i++];
    for (; i + 1 < argc; i += 2) {
        const std::string k = argv[i], v = argv[i + 1];
        if (k == "--size") {
            c.size = std::stoi(v);
        } else if (k == "--seconds") {
            c.seconds = std::stod(v);
            secondsGiven = true;
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
            c.integrator = v == "static"  ? Integrator::quasiStatic
                           : v == "euler" ? Integrator::backwardEuler
                                          : Integrator::newmark;
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
        } else if (k == "--contact") {
            if (v != "slide" && v != "jump") {
                std::fprintf(stderr, "bench_async: --contact expects slide or jump, found %s\n",
                             v.c_str());
                return 2;
            }
            c.contact = v;
        } else if (k == "--filter-mm") {
            c.filterMm = std::stod(v);
        } else if (k == "--k") {
            c.stiffness = std::stod(v);
        } else if (k == "--damping-ratio") {
            c.dampingRatio = std::stod(v);
        } else if (k == "--lead") {
            c.leadMs = std::stod(v);
        } else if (k == "--plain-lead") {
            c.lead = std::stod(v);
        } else if (k == "--coupling") {
            c.condensed = v != "plain";
        } else if (k == "--n") {
            c.nodesGiven = true;
            c.nodes.clear();
            for (double x : parseList(v)) c.nodes.push_back(static_cast<int>(x));
        } else if (k == "--f") {
            c.rates = parseList(v);
        } else {
            std::fprintf(stderr, "bench_async: unknown option %s\n", k.c_str());
            return 2;
        }
    }
    if (c.mode == "threaded" && c.moveMs > 0 && !secondsGiven) c.seconds = 6.0;
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
    } else if (c.mode == "stability") {
        stability(c);
    } else {
        std::fprintf(stderr, "bench_async: unknown mode %s\n", c.mode.c_str());
        return 2;
    }
    return 0;
}
