// palp sweep: the error-analysis Monte Carlo sweep (docs/error_analysis.md) on one process, as a
// shard of a Slurm job array (--shard i/n), or under MPI (--mpi: rank 0 hands chunks of samples
// to the ranks, itself included); `palp sweep merge DIR -o table.csv` merges the shards.
#include <algorithm>
#include <chrono>
#include <cstdio>
#include <filesystem>
#include <memory>
#include <string>
#include <thread>

#ifdef PALP_HAVE_MPI
#include <mpi.h>
#endif

#include "commands.h"
#include "palp/base/error.h"
#include "palp/studies/sweep_store.h"

namespace palp::tool {

namespace fs = std::filesystem;
using namespace palp::haptics;

namespace {

struct SweepArgs {
    std::string ranges;
    std::int64_t samples = 0;
    std::uint64_t seed = 1;
    std::string design = "lhs";
    std::string out;
    std::string shard;
    bool resume = false;
    bool mpi = false;
    std::int64_t chunkGroups = 0;
    std::int64_t maxSamples = -1;
    // merge
    std::string mergeDir;
    std::string table;
};

using Clock = std::chrono::steady_clock;

/// Progress and figures on stderr unless --quiet.
#define PALP_SWEEP_SAY(...)                                      \
    do {                                                         \
        if (!globals().quiet) std::fprintf(stderr, __VA_ARGS__); \
    } while (false)

SweepSpec specOf(const SweepArgs& a) {
    if (a.design != "lhs" && a.design != "mc")
        throw ValueError("--design: expected lhs or mc, found '" + a.design + "'");
    SweepSpec s;
    s.ranges = loadSweepRanges(a.ranges);
    s.design = a.design == "lhs" ? SweepDesign::lhs : SweepDesign::mc;
    s.seed = a.seed;
    s.samples = a.samples;
    return s;
}

/// Chunk size in samples: --chunk groups, or by default about a quarter of a worker's share.
std::int64_t chunkOf(const SweepSpec& s, const SweepArgs& a, std::int64_t workers,
                     std::int64_t rangeSize) {
    std::int64_t groups = a.chunkGroups;
    if (groups <= 0) {
        const std::int64_t g = (rangeSize + s.groupSize() - 1) / s.groupSize();
        groups = std::max<std::int64_t>(1, g / (4 * workers));
    }
    return groups * s.groupSize();
}

/// The missing parts of @p want cut into chunks that start on multiples of @p chunk.
std::vector<SampleRange> chunks(const std::vector<SampleRange>& missing, std::int64_t chunk) {
    std::vector<SampleRange> out;
    for (const auto& m : missing) {
        std::int64_t at = m.first;
        while (at < m.end) {
            const std::int64_t end = std::min(m.end, (at / chunk + 1) * chunk);
            out.push_back({at, end});
            at = end;
        }
    }
    return out;
}

std::vector<SampleRange> todo(const fs::path& dir, const SweepSpec& spec, const SampleRange& want,
                              bool resume) {
    if (!resume) return {want};
    const auto have = listShards(dir, spec, false, [](const std::string& w) {
        std::fprintf(stderr, "palp sweep: %s\n", w.c_str());
    });
    return missingRanges(want, have);
}

struct Tally {
    std::int64_t samples = 0;
    double busySeconds = 0;
};

/// Runs @p work (ranges) with chunked shards; stops after maxSamples when >= 0.
Tally runWork(const fs::path& dir, SweepRunner& runner, const std::vector<SampleRange>& work,
              std::int64_t chunk, std::int64_t maxSamples) {
    Tally t;
    const std::string host = sweepHostName();
    for (SampleRange r : work) {
        if (maxSamples >= 0) {
            const std::int64_t left = maxSamples - t.samples;
            if (left <= 0) break;
            r.end = std::min(r.end, r.first + left);
        }
        t.busySeconds += runRange(dir, runner, r, chunk, host);
        t.samples += r.size();
    }
    return t;
}

int mergeCommand(const SweepArgs& a) {
    if (a.table.empty()) throw ValueError("palp sweep merge: -o TABLE.csv is required");
    const std::int64_t rows = mergeSweep(a.mergeDir, a.table);
    PALP_SWEEP_SAY("palp sweep: merged %s into %s (%lld rows)\n", a.mergeDir.c_str(),
                   a.table.c_str(), static_cast<long long>(rows));
    return 0;
}

#ifdef PALP_HAVE_MPI
constexpr int kTagRequest = 1, kTagWork = 2;

int mpiSweep(const SweepArgs& a, const SweepSpec& spec) {
    int provided = 0;
    MPI_Init_thread(nullptr, nullptr, MPI_THREAD_SINGLE, &provided);
    int rank = 0, size = 1;
    MPI_Comm_rank(MPI_COMM_WORLD, &rank);
    MPI_Comm_size(MPI_COMM_WORLD, &size);
    const fs::path dir(a.out);
    int ok = 1;
    std::string why;
    std::vector<SampleRange> queue;
    std::int64_t chunk = 0;
    if (rank == 0) {
        try {
            prepareSweepDir(dir, spec);
            const SampleRange all{0, spec.samples};
            chunk = chunkOf(spec, a, size, spec.samples);
            queue = chunks(todo(dir, spec, all, a.resume), chunk);
        } catch (const std::exception& e) {
            ok = 0;
            why = e.what();
        }
    }
    MPI_Bcast(&ok, 1, MPI_INT, 0, MPI_COMM_WORLD);
    if (!ok) {
        MPI_Finalize();
        throw ValueError(rank == 0 ? why : "rank 0 refused the sweep");
    }
    MPI_Bcast(&chunk, 1, MPI_INT64_T, 0, MPI_COMM_WORLD);
    SweepRunner runner(spec);
    const auto start = Clock::now();
    Tally mine;
    const std::string host = sweepHostName();
    if (rank == 0) {
        // Manager and worker: answers requests between its own samples.
        std::size_t next = 0;
        int stopped = 0;
        auto serve = [&](bool block) {
            for (;;) {
                int flag = 0;
                MPI_Status st;
                if (block)
                    MPI_Probe(MPI_ANY_SOURCE, kTagRequest, MPI_COMM_WORLD, &st), flag = 1;
                else
                    MPI_Iprobe(MPI_ANY_SOURCE, kTagRequest, MPI_COMM_WORLD, &flag, &st);
                if (!flag) return;
                int dummy = 0;
                MPI_Recv(&dummy, 1, MPI_INT, st.MPI_SOURCE, kTagRequest, MPI_COMM_WORLD,
                         MPI_STATUS_IGNORE);
                std::int64_t range[2] = {0, 0};
                if (next < queue.size()) {
                    range[0] = queue[next].first;
                    range[1] = queue[next].end;
                    ++next;
                } else {
                    ++stopped;
                }
                MPI_Send(range, 2, MPI_INT64_T, st.MPI_SOURCE, kTagWork, MPI_COMM_WORLD);
                if (block) return;
            }
        };
        while (next < queue.size()) {
            const SampleRange r = queue[next++];
            std::vector<SweepSampleResult> part;
            for (std::int64_t i = r.first; i < r.end; ++i) {
                part.push_back(runner.run(i));
                mine.busySeconds += part.back().asyncSeconds + part.back().referenceSeconds;
                serve(false);
            }
            writeShard(dir, spec, part, host);
            mine.samples += r.size();
        }
        while (stopped < size - 1) serve(true);
    } else {
        for (;;) {
            int dummy = 0;
            MPI_Send(&dummy, 1, MPI_INT, 0, kTagRequest, MPI_COMM_WORLD);
            std::int64_t range[2];
            MPI_Recv(range, 2, MPI_INT64_T, 0, kTagWork, MPI_COMM_WORLD, MPI_STATUS_IGNORE);
            if (range[1] <= range[0]) break;
            const Tally t = runWork(dir, runner, {{range[0], range[1]}}, range[1] - range[0], -1);
            mine.samples += t.samples;
            mine.busySeconds += t.busySeconds;
        }
    }
    std::int64_t total = 0;
    MPI_Reduce(&mine.samples, &total, 1, MPI_INT64_T, MPI_SUM, 0, MPI_COMM_WORLD);
    const double wall = std::chrono::duration<double>(Clock::now() - start).count();
    int rc = 0;
    if (rank == 0) {
        PALP_SWEEP_SAY("palp sweep: %s: %d ranks, %lld samples in %.2f s (%.2f samples/s/rank)\n",
                       spec.id().c_str(), size, static_cast<long long>(total), wall,
                       wall > 0 ? static_cast<double>(total) / wall / size : 0.0);
        try {
            mergeSweep(dir, dir / "table.csv");
            PALP_SWEEP_SAY("palp sweep: table %s\n", (dir / "table.csv").c_str());
        } catch (const palp::Error& e) {
            std::fprintf(stderr, "palp: error: %s\n", e.what());
            rc = 1;
        }
    }
    MPI_Bcast(&rc, 1, MPI_INT, 0, MPI_COMM_WORLD);
    MPI_Finalize();
    return rc;
}
#endif

int sweepCommand(const SweepArgs& a) {
    if (a.ranges.empty()) throw ValueError("palp sweep: expected a RANGES.json argument");
    if (a.out.empty()) throw ValueError("palp sweep: -o DIR is required");
    if (a.samples < 1) throw ValueError("palp sweep: --samples N is required (N >= 1)");
    const SweepSpec spec = specOf(a);
    SweepSampler check(spec);  // refuses a bad sample count before anything is written
    (void)check;
    if (a.mpi) {
#ifdef PALP_HAVE_MPI
        if (!a.shard.empty()) throw ValueError("--mpi and --shard exclude each other");
        if (a.maxSamples >= 0) throw ValueError("--max-samples: not with --mpi (use --shard)");
        try {
            return mpiSweep(a, spec);
        } catch (const std::exception& e) {
            // A rank that fails mid-sweep would leave the others waiting on it: end the job
            // (its written shards stay; --resume continues).
            int initialised = 0, finalised = 0;
            MPI_Initialized(&initialised);
            MPI_Finalized(&finalised);
            if (initialised && !finalised) {
                std::fprintf(stderr, "palp: error: %s\n", e.what());
                MPI_Abort(MPI_COMM_WORLD, 1);
            }
            throw;
        }
#else
        throw ValueError("--mpi: this palp was built without MPI (install libopenmpi-dev)");
#endif
    }
    const fs::path dir(a.out);
    prepareSweepDir(dir, spec);
    SampleRange want{0, spec.samples};
    if (!a.shard.empty()) {
        const auto [i, n] = parseShard(a.shard);
        want = shardRange(spec, i, n);
    }
    // Chunks of about a quarter of the range (whole groups) unless --chunk says: a task that
    // dies (a Slurm time limit, a node lost) then costs at most its unfinished chunk.
    const std::int64_t chunk = chunkOf(spec, a, 1, want.size());
    const auto work = chunks(todo(dir, spec, want, a.resume), chunk);
    std::int64_t pending = 0;
    for (const auto& w : work) pending += w.size();
    SweepRunner runner(spec);
    const auto start = Clock::now();
    const Tally t = runWork(dir, runner, work, chunk, a.maxSamples);
    const double wall = std::chrono::duration<double>(Clock::now() - start).count();
    PALP_SWEEP_SAY(
        "palp sweep: %s samples [%lld, %lld): %lld computed in %.2f s (%.4f s/sample, %.2f "
        "samples/s on one core; %d references)\n",
        spec.id().c_str(), static_cast<long long>(want.first), static_cast<long long>(want.end),
        static_cast<long long>(t.samples), wall,
        t.samples ? wall / static_cast<double>(t.samples) : 0.0,
        wall > 0 ? static_cast<double>(t.samples) / wall : 0.0, runner.referencesComputed());
    if (t.samples < pending) {
        std::fprintf(stderr,
                     "palp sweep: stopped after --max-samples %lld; %lld samples left "
                     "for --resume\n",
                     static_cast<long long>(a.maxSamples),
                     static_cast<long long>(pending - t.samples));
        return 3;
    }
    if (a.shard.empty()) {
        mergeSweep(dir, dir / "table.csv");
        PALP_SWEEP_SAY("palp sweep: table %s\n", (dir / "table.csv").c_str());
    }
    return 0;
}

}  // namespace

Command addSweep(CLI::App& root) {
    auto args = std::make_shared<SweepArgs>();
    CLI::App* app = root.add_subcommand(
        "sweep",
        "Error-analysis Monte Carlo sweep of the asynchronous regions against the "
        "whole mesh (docs/error_analysis.md)");
    app->add_option("ranges", args->ranges, "Ranges file (JSON)");
    app->add_option("--samples,-n", args->samples, "Number of samples")
        ->check(CLI::Range(1, 1000000000));
    app->add_option("--seed", args->seed, "Seed of the Philox streams")->capture_default_str();
    app->add_option("--design", args->design, "lhs (Latin hypercube) or mc (plain Monte Carlo)")
        ->check(CLI::IsMember({"lhs", "mc"}))
        ->capture_default_str();
    app->add_option("-o,--out", args->out, "Sweep directory (manifest, shards, table.csv)");
    app->add_option("--shard", args->shard,
                    "i/n: this process computes shard i of n (e.g. "
                    "$SLURM_ARRAY_TASK_ID/$SLURM_ARRAY_TASK_COUNT)");
    app->add_flag("--resume", args->resume,
                  "Compute only the samples no intact shard in the directory holds");
    app->add_flag("--mpi", args->mpi, "Under mpirun / srun: rank 0 hands chunks to every rank");
    app->add_option("--chunk", args->chunkGroups,
                    "Groups (of adaptivity_per_reference samples) per shard file (default: about a "
                    "quarter of the process's range, or of a rank's share under --mpi)")
        ->check(CLI::Range(1, 1000000000));
    app->add_option("--max-samples", args->maxSamples,
                    "Compute at most this many samples, then stop (exit 3; --resume continues)")
        ->check(CLI::Range(0, 1000000000));
    CLI::App* merge = app->add_subcommand("merge", "Merge a sweep directory's shards into a table");
    merge->add_option("dir", args->mergeDir, "Sweep directory")->required();
    merge->add_option("-o,--out", args->table, "Table (CSV; the sidecar JSON goes beside it)")
        ->required();
    return {app, [args, merge]() -> int {
                if (merge->parsed()) return mergeCommand(*args);
                return sweepCommand(*args);
            }};
}

}  // namespace palp::tool
