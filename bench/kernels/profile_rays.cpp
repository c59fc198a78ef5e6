// Traces the volume bench's bundles with palp's first-hit only (no baseline), for instruction
// counts under callgrind:
//   valgrind --tool=callgrind --toggle-collect='palp::kernels::traceFirstHit*'
//       build/rays/bench/kernels/profile_rays phantom|FILE.vdb trajectory|random FRAMES [RAYS]
//       [scalar] [field] [scalar]
// (one command line). With `compare` as the fifth argument it traces every bundle with and without
// a HitField and prints how far the two paths' hits differ.
// and prints the number of rays hit (so the work cannot be optimised away).
//
// With `sequence` (and `field`) it times each bundle's first trace and an immediate second one,
// in the bench's order (how much of a frame is new data and new branches); with `sequence
// reversed` the first trace is of the bundle with its rays in reverse order (the same data,
// other branch history), so the second trace's time less the plain second trace's is what
// branch history costs. Both on the wall clock: reading the thread CPU clock is a system call
// that costs more than a bundle on some virtual machines.
//
// With `flush WHAT field` each bundle is traced once, then the cache lines its march read from
// the arrays named in WHAT (e: the field's entries, m: its masks, c: the blended cells' corners
// in the block copies, t: the table's per-block arrays and the per-mask copy offsets; `none`)
// are flushed with clflush and the bundle is traced again: what those arrays' misses alone cost.
//
// With `percentiles` (or `percentiles-cold`) as the fifth argument it times every bundle on the
// thread CPU clock instead (best of 5 back-to-back calls: hot caches; or one call after writing
// 8 MiB: cold caches) and prints mean, p50, p90, p99 and p99.9 of the per-bundle time, each
// with the average make-up of the samples up to the hit of the ten bundles around it: in a
// skippable block, in a 4^3 sub-block below the threshold, in a cell whose eight corners are all
// below it, or none of these.
#include <immintrin.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <ctime>
#include <exception>
#include <memory>
#include <string>
#include <vector>

#include "palp/bench/ray_bench.h"
#include "palp/kernels/volume_ray.h"
#include "view_table.h"  // kernels/src (internal)

namespace {

using namespace palp::kernels;

double cpuUs() {
    timespec ts{};
    clock_gettime(CLOCK_THREAD_CPUTIME_ID, &ts);
    return static_cast<double>(ts.tv_sec) * 1e6 + static_cast<double>(ts.tv_nsec) * 1e-3;
}

double wallUs() {
    return std::chrono::duration<double, std::micro>(
               std::chrono::steady_clock::now().time_since_epoch())
        .count();
}

/// Prints mean, p50, p90 and p99 of @p us (sorted here).
void printTimes(const char* label, std::vector<double>& us) {
    double sum = 0;
    for (const double x : us) sum += x;
    std::sort(us.begin(), us.end());
    std::printf("%s: mean %.2f us, p50 %.2f, p90 %.2f, p99 %.2f\n", label,
                sum / static_cast<double>(us.size()), us[us.size() / 2], us[us.size() * 9 / 10],
                us[us.size() * 99 / 100]);
}

struct BundleProfile {
    double us = 0;
    double block = 0, sub = 0, cell = 0, must = 0;  // samples up to the hit, by kind
    double hits = 0, hotBlocks = 0;                 // rays that hit; visits of non-skippable blocks
    std::size_t index = 0;
};

// Calls @p visit(ray, block, ix, iy, iz) at every sample (t = k @p step) of every
// ray of @p b up to its hit (from @p hits) that lies in the view's table: the table block index
// and the table-relative voxel.
template <class Visit>
void forEachSample(const VolumeView& view, const RayBundle& b, const BundleHits& hits, double step,
                   Visit&& visit) {
    const auto& tb = detail::viewTable(view);
    for (int r = 0; r < b.count; ++r) {
        const auto i = static_cast<std::size_t>(r);
        const Eigen::Vector3d o(b.ox[i], b.oy[i], b.oz[i]);
        const Eigen::Vector3d d = Eigen::Vector3d(b.dx[i], b.dy[i], b.dz[i]).normalized();
        const double len = b.length[i];
        const double tEnd = hits.hit[i] ? static_cast<double>(hits.t[i]) : len;
        const auto kEnd = static_cast<int>(std::ceil(tEnd / step - 1e-9));
        for (int k = 0; k <= kEnd; ++k) {
            const Eigen::Vector3d x = view.indexFromWorld(o + std::min(k * step, len) * d);
            const auto ix = static_cast<long>(std::floor(x.x())) - tb.origin[0];
            const auto iy = static_cast<long>(std::floor(x.y())) - tb.origin[1];
            const auto iz = static_cast<long>(std::floor(x.z())) - tb.origin[2];
            if (ix < 0 || iy < 0 || iz < 0 || (ix >> 3) >= tb.blocks[0] ||
                (iy >> 3) >= tb.blocks[1] || (iz >> 3) >= tb.blocks[2])
                continue;
            const auto blk = static_cast<std::size_t>(
                ((ix >> 3) * tb.blocks[1] + (iy >> 3)) * tb.blocks[2] + (iz >> 3));
            visit(r, blk, ix, iy, iz);
        }
    }
}

// Classifies the lattice samples of every ray of @p b up to its hit (from @p hits).
void classify(const VolumeView& view, const RayBundle& b, const BundleHits& hits, double step,
              float thr, BundleProfile& p) {
    const auto& tb = detail::viewTable(view);
    for (int r = 0; r < b.count; ++r) p.hits += hits.hit[static_cast<std::size_t>(r)];
    std::size_t lastHot = ~std::size_t{0};
    int lastRay = -1;
    forEachSample(view, b, hits, step, [&](int ray, std::size_t blk, long ix, long iy, long iz) {
        if (ray != lastRay) lastHot = ~std::size_t{0};
        lastRay = ray;
        if (tb.maxDilated[blk] < thr) {
            p.block += 1;
            return;
        }
        if (blk != lastHot) p.hotBlocks += 1;
        lastHot = blk;
        const float* copy = tb.data[blk];
        const long lx = ix & 7, ly = iy & 7, lz = iz & 7;
        const auto c = static_cast<std::size_t>(copy - tb.padded) /
                       static_cast<std::size_t>(detail::ViewTable::kPadded);
        const auto s = static_cast<std::size_t>(((lx >> 2) << 2) | ((ly >> 2) << 1) | (lz >> 2));
        if (tb.subMax[c * detail::ViewTable::kSubBlocks + s] < thr) {
            p.sub += 1;
            return;
        }
        float mx = copy[(lx * 9 + ly) * 9 + lz];
        for (long n = 1; n < 8; ++n)
            mx = std::max(mx, copy[((lx + (n >> 2)) * 9 + ly + ((n >> 1) & 1)) * 9 + lz + (n & 1)]);
        (mx < thr ? p.cell : p.must) += 1;
    });
}

/// The cache lines a bundle's lattice march reads up to each ray's hit, by array: the field's
/// entries, its masks, and the block copies' corners of the cells it blends.
struct TouchedLines {
    std::vector<const void*> entries, masks, copies, tables;
};

void touchedLines(const VolumeView& view, const HitField& field, const RayBundle& b,
                  const BundleHits& hits, double step, TouchedLines& out) {
    const auto& tb = detail::viewTable(view);
    forEachSample(view, b, hits, step, [&](int, std::size_t blk, long ix, long iy, long iz) {
        out.entries.push_back(field.entries() + blk);
        out.tables.push_back(tb.data.data() + blk);
        out.tables.push_back(tb.maxDilated.data() + blk);
        out.tables.push_back(field.maskCopyOffsets() +
                             (field.entry(blk) >> HitField::kDistanceBits));
        if (field.blockDistance(blk) != 0) return;
        out.masks.push_back(field.blockMask(blk));
        const long lx = ix & 7, ly = iy & 7, lz = iz & 7;
        if (!field.cellCanReach(blk, static_cast<unsigned>((lx * 8 + ly) * 8 + lz))) return;
        const float* c =
            field.maskCopy(field.entry(blk) >> HitField::kDistanceBits) + (lx * 9 + ly) * 9 + lz;
        for (const int off : {0, 1, 9, 10, 81, 82, 90, 91}) out.copies.push_back(c + off);
    });
}

void percentiles(const std::vector<RayBundle>& bundles, const VolumeView& view,
                 const FirstHitParams& fp, bool cold, bool slowest) {
    std::vector<BundleProfile> prof(bundles.size());
    std::vector<char> junk(std::size_t{8} << 20);
    BundleHits hits;
    char salt = 0;
    for (std::size_t f = 0; f < bundles.size(); ++f) {
        double best = 1e30;
        if (cold) {
            ++salt;
            for (std::size_t q = 0; q < junk.size(); q += 64)
                junk[q] = static_cast<char>(junk[q] + salt);
            const double c0 = cpuUs();
            traceFirstHit(view, bundles[f], fp, hits);
            best = cpuUs() - c0;
        } else {
            for (int rep = 0; rep < 5; ++rep) {
                const double c0 = cpuUs();
                traceFirstHit(view, bundles[f], fp, hits);
                best = std::min(best, cpuUs() - c0);
            }
        }
        prof[f].us = best;
        prof[f].index = f;
        classify(view, bundles[f], hits, fp.step, fp.threshold, prof[f]);
    }
    std::sort(prof.begin(), prof.end(),
              [](const BundleProfile& a, const BundleProfile& b) { return a.us < b.us; });
    auto print = [&](const char* name, std::size_t lo, std::size_t hi) {
        BundleProfile a;
        for (std::size_t i = lo; i < hi; ++i) {
            a.us += prof[i].us;
            a.block += prof[i].block;
            a.sub += prof[i].sub;
            a.cell += prof[i].cell;
            a.must += prof[i].must;
            a.hits += prof[i].hits;
            a.hotBlocks += prof[i].hotBlocks;
        }
        const auto n = static_cast<double>(hi - lo);
        std::printf(
            "%-6s %7.2f us  samples: skippable block %5.0f, empty 4^3 sub-block %5.0f, cell below "
            "threshold %4.0f, other %4.0f; hits %4.1f, block entries %4.1f\n",
            name, a.us / n, a.block / n, a.sub / n, a.cell / n, a.must / n, a.hits / n,
            a.hotBlocks / n);
    };
    print("mean", 0, prof.size());
    const std::pair<const char*, double> qs[] = {
        {"p50", 0.5}, {"p90", 0.9}, {"p99", 0.99}, {"p99.9", 0.999}};
    for (const auto& [name, q] : qs) {
        const auto c = static_cast<std::size_t>(q * static_cast<double>(prof.size()));
        const std::size_t lo = c >= 5 ? c - 5 : 0, hi = std::min(prof.size(), c + 5);
        print(name, lo, std::max(hi, lo + 1));
    }
    if (slowest) {
        // The slowest 2 % of the bundles, traced over and over (for perf record).
        const std::size_t first = prof.size() - prof.size() / 50;
        const double c0 = cpuUs();
        std::size_t n = 0;
        while (cpuUs() - c0 < 5e6) {
            for (std::size_t i = first; i < prof.size(); ++i, ++n)
                traceFirstHit(view, bundles[prof[i].index], fp, hits);
        }
        std::printf("slowest 2 %%: %.2f us per bundle over %zu traces\n",
                    (cpuUs() - c0) / static_cast<double>(n), n);
    }
}

}  // namespace

int main(int argc, char** argv) {
    try {
        if (argc < 4) {
            std::fprintf(stderr,
                         "usage: profile_rays phantom|FILE.vdb trajectory|random FRAMES [RAYS] "
                         "[scalar|percentiles|percentiles-cold]\n");
            return 2;
        }
        const std::string src = argv[1];
        const bool trajectory = std::string(argv[2]) == "trajectory";
        const std::string mode = argc > 5 ? argv[5] : "";
        bool useField = false, scalar = mode == "scalar";
        for (int a = 6; a < argc; ++a) {
            useField =
                useField || std::string(argv[a]) == "field" || std::string(argv[a]) == "reversed";
            scalar = scalar || std::string(argv[a]) == "scalar";
        }
        RayBenchOptions o;
        o.frames = std::atoi(argv[3]);
        if (argc > 4) o.rays = std::atoi(argv[4]);
        openvdb::FloatGrid::Ptr grid;
        if (src == "phantom") {
            grid = makeRayBenchPhantom();
        } else {
            openvdb::initialize();
            openvdb::io::File f(src);
            f.open();
            grid = openvdb::gridPtrCast<openvdb::FloatGrid>(f.getGrids()->front());
        }
        const auto bundles = volumeBenchBundles(*grid, src == "phantom", trajectory, o);
        const VolumeView view(grid);
        FirstHitParams fp;
        fp.threshold = o.threshold;
        fp.step = o.step;
        fp.simd = !scalar;
        if (std::getenv("PALP_REFINE")) fp.refineIterations = std::atoi(std::getenv("PALP_REFINE"));
        std::unique_ptr<HitField> field;
        if (useField) {
            field = std::make_unique<HitField>(view, fp.threshold);
            fp.field = field.get();
            std::printf("hit field: %zu hot copies, %.1f MiB\n", field->hotCopies(),
                        static_cast<double>(field->bytes()) / (1 << 20));
        }
        if (mode == "compare") {
            // The field path against the block-run path without a field, ray by ray.
            const HitField f(view, fp.threshold);
            FirstHitParams withField = fp;
            withField.field = &f;
            BundleHits a, b;
            long rays = 0, hitMismatch = 0, hits = 0;
            double worst = 0;
            for (const auto& bundle : bundles) {
                traceFirstHit(view, bundle, fp, a);
                traceFirstHit(view, bundle, withField, b);
                for (int r = 0; r < a.count; ++r) {
                    const auto i = static_cast<std::size_t>(r);
                    ++rays;
                    hits += a.hit[i];
                    if (a.hit[i] != b.hit[i]) {
                        ++hitMismatch;
                        continue;
                    }
                    worst = std::max(
                        worst, std::fabs(static_cast<double>(a.t[i]) - b.t[i]) / view.voxelSize());
                }
            }
            std::printf(
                "%ld rays, %ld hits; field vs no field: %ld hit/miss differences, largest "
                "t difference %.2e voxel\n",
                rays, hits, hitMismatch, worst);
            return 0;
        }
        if (mode == "sequence") {
            // Each bundle traced once in the bench's order (no baseline in between), then again
            // at once: the first trace finds the data of the frames before and branch history
            // from other bundles; the second, this bundle's own.
            // With "reversed" the first trace is of the bundle with its rays in reverse order
            // (the same data, other branch history), then the bundle itself is timed.
            const bool reversed = argc > 6 && std::string(argv[6]) == "reversed";
            std::vector<double> first, second;
            BundleHits h;
            RayBundle rev;
            for (const auto& bundle : bundles) {
                rev = bundle;
                for (int r = 0; r < bundle.count; ++r) {
                    const auto a = static_cast<std::size_t>(r),
                               b = static_cast<std::size_t>(bundle.count - 1 - r);
                    rev.ox[a] = bundle.ox[b];
                    rev.oy[a] = bundle.oy[b];
                    rev.oz[a] = bundle.oz[b];
                    rev.dx[a] = bundle.dx[b];
                    rev.dy[a] = bundle.dy[b];
                    rev.dz[a] = bundle.dz[b];
                    rev.length[a] = bundle.length[b];
                }
                double c0 = wallUs();
                traceFirstHit(view, reversed ? rev : bundle, fp, h);
                first.push_back(wallUs() - c0);
                c0 = wallUs();
                traceFirstHit(view, bundle, fp, h);
                second.push_back(wallUs() - c0);
            }
            printTimes("first  trace", first);
            printTimes("second trace", second);
            return 0;
        }
        if (mode == "flush" && field) {
            // Each bundle traced once, then the lines of the arrays named in argv[6] that its
            // march reads are flushed from every cache level, and the bundle is traced again.
            // (The first trace here follows the previous bundle's walk below, not its trace.)
            const std::string what = argc > 6 ? argv[6] : "none";
            std::vector<double> us, firstUs;
            BundleHits h;
            TouchedLines lines;
            for (const auto& bundle : bundles) {
                double c0 = wallUs();
                traceFirstHit(view, bundle, fp, h);
                firstUs.push_back(wallUs() - c0);
                lines.entries.clear();
                lines.masks.clear();
                lines.copies.clear();
                lines.tables.clear();
                touchedLines(view, *field, bundle, h, fp.step, lines);
                auto flush = [](const std::vector<const void*>& v) {
                    for (const void* a : v) _mm_clflush(a);
                };
                if (what.find('e') != std::string::npos) flush(lines.entries);
                if (what.find('m') != std::string::npos) flush(lines.masks);
                if (what.find('c') != std::string::npos) flush(lines.copies);
                if (what.find('t') != std::string::npos) flush(lines.tables);
                _mm_mfence();
                c0 = wallUs();
                traceFirstHit(view, bundle, fp, h);
                us.push_back(wallUs() - c0);
            }
            printTimes("first trace ", firstUs);
            printTimes(("flushed " + what).c_str(), us);
            return 0;
        }
        if (mode == "percentiles" || mode == "percentiles-cold" || mode == "slowest") {
            percentiles(bundles, view, fp, mode == "percentiles-cold", mode == "slowest");
            return 0;
        }
        BundleHits hits;
        long hitCount = 0;
        for (const auto& b : bundles) {
            traceFirstHit(view, b, fp, hits);
            for (int r = 0; r < hits.count; ++r) hitCount += hits.hit[static_cast<std::size_t>(r)];
        }
        std::printf("%zu bundles, %ld rays hit\n", bundles.size(), hitCount);
        return 0;
    } catch (const std::exception& e) {
        std::fprintf(stderr, "profile_rays: error: %s\n", e.what());
        return 1;
    }
}
