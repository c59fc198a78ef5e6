#include "regions/secondary_thread.h"

#if defined(__GLIBC__)
#include <malloc.h>
#endif

#include <algorithm>
#include <array>
#include <cstdlib>

#include "palp/base/parallel.h"
#include "palp/base/thread.h"

namespace palp::fem {

LayoutChannel::~LayoutChannel() {
    delete pending.exchange(nullptr);
    delete retired.exchange(nullptr);
}

bool LayoutChannel::wanted(const Layout& L, int want) const noexcept {
    return want >= 0 && want != rejected &&
           !(L.contactNodes.size() == 1 && L.contactNodes[0] == want);
}

SecondaryThread::SecondaryThread(const AsyncSetup& setup, const LayoutBuilder& builder,
                                 SecondaryRegion& secondary, BorderExchange& exchange,
                                 LayoutChannel& channel, Layout& initial, tbb::task_arena& arena)
    : mSetup(setup),
      mBuilder(builder),
      mSecondary(secondary),
      mExchange(exchange),
      mChannel(channel),
      mArena(arena),
      mSec(&initial),
      mBuildBegin(std::chrono::steady_clock::now()),
      mWorker([this] { run(); }) {}

SecondaryThread::~SecondaryThread() {
    mStop.store(true, std::memory_order_release);
    if (mWorker.joinable()) mWorker.join();
}

void SecondaryThread::run() {
    nameCurrentThread("palp-secondary");
    if (mSetup.options.secondaryCpu >= 0) pinCurrentThread(mSetup.options.secondaryCpu);
    // One builder for the regions' life, started here so it inherits this thread's CPU and
    // priority: a sliding contact needs its next layout within a node's travel (~100 ms), and at
    // nice 10 a 40 ms build took over a second on a core shared with other work. One thread,
    // not one per build: glibc gives each new thread an arena of its own choosing, and layouts
    // (megabytes each, built and freed as the contact moves) spread over several arenas kept the
    // resident set creeping up for an hour (bench/README.md, "Soak").
    try {
        mBuilderThread = std::thread([this] { buildLoop(); });
    } catch (...) {
        // No thread to spare: no layout is built, so the regions keep the layout in use (the
        // servo's contact changes are refused as a failed build would be).
        mBuildState.store(kFailed, std::memory_order_release);
    }
    arenaExecute(mArena, [this] {
        while (!mStop.load(std::memory_order_acquire)) {
            if (Layout* old = mChannel.retired.exchange(nullptr, std::memory_order_acq_rel)) {
                mSec = mOffered;  // the servo adopted the offered layout
                mOffered = nullptr;
                mLastStep = latticeStep(old->contactNodes[0], mSec->contactNodes[0]);
                delete old;
                trimHeap();
            }
            if (mOffered != nullptr || mStalled.load(std::memory_order_acquire)) {
                std::this_thread::sleep_for(std::chrono::microseconds(50));
                continue;
            }
            if (collectBuild()) continue;
            const int want = mChannel.requested.load(std::memory_order_acquire);
            track(want);
            const bool idle = mBuildState.load(std::memory_order_acquire) == kIdle;
            if (mChannel.wanted(*mSec, want)) {
                if (offerCached(want)) continue;
                if (idle) startBuild(ahead(want), false);
            } else if (idle) {
                prefetch();
            }
            if (!mExchange.snapshots.update()) {
                std::this_thread::sleep_for(std::chrono::microseconds(50));
                continue;
            }
            const BorderPacket& in = mExchange.snapshots.front().value;
            if (in.generation != mSec->generation) continue;  // from before the last swap
            solveSnapshot(in);
        }
    });
    if (mBuilderThread.joinable()) {
        {
            std::lock_guard<std::mutex> lock(mBuildMutex);
            mBuilderStop = true;
        }
        mBuildWake.notify_one();
        mBuilderThread.join();  // after the build in progress, if any
    }
}

void SecondaryThread::buildLoop() {
    nameCurrentThread("palp-layout");
    for (;;) {
        BuildRequest r;
        {
            std::unique_lock<std::mutex> lock(mBuildMutex);
            mBuildWake.wait(lock, [this] { return mPosted || mBuilderStop; });
            if (mBuilderStop) return;
            r = mRequest;
            mPosted = false;
        }
        try {
            // A prefetch never factorises: that would hold the builder for seconds while the
            // contact moves on to a node whose layout is milliseconds.
            mBuilt = mBuilder.buildPrepared(r.node, r.seeds, r.prefetch);
            const double delay = mBuildDelay.load(std::memory_order_acquire);
            if (delay > 0) std::this_thread::sleep_for(std::chrono::duration<double>(delay));
            mBuildState.store(kBuilt, std::memory_order_release);
        } catch (...) {
            mBuilt.reset();
            mBuildState.store(kFailed, std::memory_order_release);
        }
    }
}

void SecondaryThread::trimHeap() {
    // A layout (its factorisation or dense responses, its zone blocks: megabytes) is freed each
    // time the contact moves on, and glibc keeps freed pages in its arenas, where later
    // allocations scatter over them: on the bone phantom's regions under a circling contact the
    // heap in use and the heap glibc held stayed flat over minutes while the resident set
    // crept up by 0.2-0.5 MiB a minute (bench_soak; bench/README.md, "Soak"). malloc_trim gives
    // every arena's free pages back; at most once a second, on this thread (never the servo's),
    // which pays its milliseconds.
#if defined(__GLIBC__)
    const auto now = std::chrono::steady_clock::now();
    if (now - mLastTrim < std::chrono::seconds(1)) return;
    mLastTrim = now;
    malloc_trim(0);
#endif
}

int SecondaryThread::latticeStep(int from, int to) const {
    // The node index step of one lattice edge from @p from towards @p to along the axis it
    // moved most (a contact that moved several nodes prefetches its next neighbour that way).
    const HexMesh& mesh = mSetup.model.mesh();
    const auto a = mesh.nodeCoords(from), b = mesh.nodeCoords(to);
    const auto& nc = mesh.nodeCounts();
    int axis = 0;
    for (int k = 1; k < 3; ++k) {
        const std::size_t i = static_cast<std::size_t>(k), m = static_cast<std::size_t>(axis);
        if (std::abs(b[i] - a[i]) > std::abs(b[m] - a[m])) axis = k;
    }
    const std::size_t m = static_cast<std::size_t>(axis);
    const int stride = axis == 0 ? 1 : axis == 1 ? nc[0] : nc[0] * nc[1];
    return b[m] > a[m] ? stride : b[m] < a[m] ? -stride : 0;
}

bool SecondaryThread::collectBuild() {
    // A finished build: add the entry state from the latest solution and offer it to the servo.
    const int state = mBuildState.load(std::memory_order_acquire);
    if (state != kBuilt && state != kFailed) return false;
    if (!mBuilderThread.joinable()) return false;  // no builder: kFailed for good, nothing built
    mBuildState.store(kIdle, std::memory_order_relaxed);
    const int want = mChannel.requested.load(std::memory_order_acquire);
    if (state == kBuilt && mBuilt == nullptr) {
        // A prefetch the capacitance secondary cannot give (e.g. a contact at the face's
        // edge, whose primary leaves the zone): not prefetched again; a request for it builds
        // and factorises it then.
        mFailed.push_back(mBuilding);
    } else if (state == kBuilt) {
        const double seconds =
            std::chrono::duration<double>(std::chrono::steady_clock::now() - mBuildBegin).count();
        mBuildSeconds = mBuildSeconds > 0 ? 0.7 * mBuildSeconds + 0.3 * seconds : seconds;
        // A request overtaken while it was built (a contact sliding faster than a node per
        // build) is still offered when it is nearer the contact than the layout in use: else
        // every build would arrive late and a fast slide would never be followed.
        if (mChannel.wanted(*mSec, want) && (mBuilding == want || nearer(mBuilding, want))) {
            offer(std::move(mBuilt));
        } else if (mBuilt->global != nullptr) {
            mCache.push_back(std::move(mBuilt));  // a prefetch, or a request overtaken
        }
    } else {
        mFailed.push_back(mBuilding);
        if (mBuilding == want) mChannel.rejected = mBuilding;  // keep the current layout
    }
    mBuilt.reset();
    return true;
}

void SecondaryThread::offer(std::unique_ptr<Layout> next) {
    try {
        mSecondary.prepareEntry(*mSec, *next, mBuildBegin);
        mOffered = next.release();
        mChannel.pending.store(mOffered, std::memory_order_release);
    } catch (...) {
        mChannel.rejected = next->contactNodes[0];
    }
}

void SecondaryThread::track(int want) {
    // The requested node's history: where the contact goes and how fast.
    if (want < 0 || (mTrackCount > 0 && mTrack[(mTrackCount - 1) % kTrack].node == want)) return;
    mTrack[mTrackCount % kTrack] = TrackPoint{std::chrono::steady_clock::now(), want};
    ++mTrackCount;
}

int SecondaryThread::ahead(int want) const {
    // A sliding contact moves on while its layout is built: build for where it will be when the
    // build is done (its velocity over the last requests times the recent build time), if that
    // is a slide node; the nearer-rule then adopts it when it serves the contact better.
    if (mTrackCount < 2 || !(mBuildSeconds > 0) || !mBuilder.isSlideNode(want)) return want;
    const TrackPoint& last = mTrack[(mTrackCount - 1) % kTrack];
    if (last.node != want) return want;
    const auto now = std::chrono::steady_clock::now();
    const std::size_t span = std::min<std::size_t>(mTrackCount, kTrack);
    const TrackPoint* first = &last;
    std::size_t used = 1;
    for (std::size_t k = 2; k <= span; ++k) {
        const TrackPoint& p = mTrack[(mTrackCount - k) % kTrack];
        if (now - p.time > std::chrono::milliseconds(150)) break;
        first = &p;
        used = k;
    }
    const double dt = std::chrono::duration<double>(now - first->time).count();
    if (used < 3 || !(dt > 0)) return want;  // a slide is three requests in a row at least
    // Stopped (or slowed at a turn): no change for twice the mean interval between changes.
    const double interval = std::chrono::duration<double>(last.time - first->time).count() /
                            static_cast<double>(used - 1);
    if (std::chrono::duration<double>(now - last.time).count() > 2 * interval) return want;
    const HexMesh& mesh = mSetup.model.mesh();
    const Eigen::Vector3d v = (mesh.nodePosition(last.node) - mesh.nodePosition(first->node)) / dt;
    const double lead = std::min(mBuildSeconds, 0.25);
    const Eigen::Vector3d step = v * lead / mesh.edge();
    std::array<int, 3> ijk = mesh.nodeCoords(want);
    const auto& nc = mesh.nodeCounts();
    for (int a = 0; a < 3; ++a) {
        const std::size_t i = static_cast<std::size_t>(a);
        ijk[i] = std::clamp(ijk[i] + static_cast<int>(std::lround(step[a])), 0, nc[i] - 1);
    }
    const int n = mesh.node(ijk[0], ijk[1], ijk[2]);
    return mBuilder.isSlideNode(n) && std::find(mFailed.begin(), mFailed.end(), n) == mFailed.end()
               ? n
               : want;
}

double SecondaryThread::distance2(int a, int b) const {
    const HexMesh& mesh = mSetup.model.mesh();
    return (mesh.nodePosition(a) - mesh.nodePosition(b)).squaredNorm();
}

bool SecondaryThread::nearer(int node, int want) const {
    // Whether a layout around @p node serves a contact at @p want better than the one in use.
    return mSec->contactNodes.size() == 1 &&
           distance2(node, want) < distance2(mSec->contactNodes[0], want);
}

bool SecondaryThread::offerCached(int want) {
    // The cached layout of the wanted node, else the cached one nearest to it when it is nearer
    // than the layout in use (a build for the wanted node then follows).
    std::size_t best = mCache.size();
    double bestD2 = 0;
    for (std::size_t i = 0; i < mCache.size(); ++i) {
        const int n = mCache[i]->contactNodes[0];
        const double d2 = distance2(n, want);
        if (n == want || (nearer(n, want) && (best == mCache.size() || d2 < bestD2))) {
            best = i;
            bestD2 = d2;
            if (n == want) break;
        }
    }
    if (best == mCache.size()) return false;
    std::unique_ptr<Layout> next = std::move(mCache[best]);
    mCache.erase(mCache.begin() + static_cast<std::ptrdiff_t>(best));
    mBuildBegin = std::chrono::steady_clock::now();
    offer(std::move(next));
    return true;
}

void SecondaryThread::prefetch() {
    // Only where layouts are cheap (the capacitance secondary): the slide neighbours of the
    // current contact, the direction of the last change first; layouts for other nodes go.
    // Only once the contact has moved (a static contact keeps the machine quiet).
    if (mSec->global == nullptr || mSec->contactNodes.size() != 1 ||
        mChannel.requested.load(std::memory_order_acquire) < 0)
        return;
    const HexMesh& mesh = mSetup.model.mesh();
    const int c = mSec->contactNodes[0];
    const auto ijk = mesh.nodeCoords(c);
    const auto& nc = mesh.nodeCounts();
    std::array<int, 6> candidates{};
    int count = 0;
    auto add = [&](int n) {
        if (n < 0 || n == c ||
            std::find(candidates.begin(), candidates.begin() + count, n) !=
                candidates.begin() + count)
            return;
        candidates[static_cast<std::size_t>(count++)] = n;
    };
    if (mLastStep != 0) {  // one lattice edge on, if the lattice goes on that way
        const auto next = mesh.nodeCoords(
            c + mLastStep >= 0 && c + mLastStep < mesh.nodeCount() ? c + mLastStep : c);
        int changed = 0;
        for (std::size_t k = 0; k < 3; ++k) changed += std::abs(next[k] - ijk[k]);
        if (changed == 1) add(c + mLastStep);
    }
    for (int a = 0; a < 3; ++a) {
        for (int s = -1; s <= 1; s += 2) {
            std::array<int, 3> q = ijk;
            q[static_cast<std::size_t>(a)] += s;
            if (q[static_cast<std::size_t>(a)] < 0 ||
                q[static_cast<std::size_t>(a)] >= nc[static_cast<std::size_t>(a)])
                continue;
            add(mesh.node(q[0], q[1], q[2]));
        }
    }
    mCache.erase(std::remove_if(mCache.begin(), mCache.end(),
                                [&](const std::unique_ptr<Layout>& L) {
                                    const int n = L->contactNodes[0];
                                    return std::find(candidates.begin(), candidates.begin() + count,
                                                     n) == candidates.begin() + count;
                                }),
                 mCache.end());
    for (int i = 0; i < count; ++i) {
        const int n = candidates[static_cast<std::size_t>(i)];
        if (!mBuilder.isSlideNode(n)) continue;
        if (std::find(mFailed.begin(), mFailed.end(), n) != mFailed.end()) continue;
        if (std::any_of(mCache.begin(), mCache.end(),
                        [&](const std::unique_ptr<Layout>& L) { return L->contactNodes[0] == n; }))
            continue;
        startBuild(n, true);
        return;
    }
}

void SecondaryThread::startBuild(int want, bool prefetch) {
    mBuilding = want;
    mBuildBegin = std::chrono::steady_clock::now();
    mBuildState.store(kBuilding, std::memory_order_relaxed);
    {
        std::lock_guard<std::mutex> lock(mBuildMutex);
        mRequest = BuildRequest{want, mSec->seeds, prefetch};
        mPosted = true;
    }
    mBuildWake.notify_one();
}

void SecondaryThread::solveSnapshot(const BorderPacket& in) {
    BorderPacket& out = mExchange.results.back().value;
    const std::size_t ng = mSec->gammaDofs.size(), nb = mSec->borderDofs.size();
    double* watchOut = mSetup.options.watchNodes.empty() ? nullptr : out.values.data() + ng + nb;
    if (!mSecondary.solve(*mSec, in.values.data(), &in, out.values.data(), watchOut)) return;
    std::copy(in.values.begin(), in.values.begin() + static_cast<std::ptrdiff_t>(nb),
              out.values.begin() + static_cast<std::ptrdiff_t>(ng));
    out.time = in.time;
    out.sequence = in.sequence;
    out.generation = mSec->generation;
    mExchange.results.publish();
}

}  // namespace palp::fem
