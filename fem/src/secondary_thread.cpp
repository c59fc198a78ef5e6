#include "secondary_thread.h"

#include <algorithm>
#include <array>

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
    mArena.execute([this] {
        while (!mStop.load(std::memory_order_acquire)) {
            if (Layout* old = mChannel.retired.exchange(nullptr, std::memory_order_acq_rel)) {
                mSec = mOffered;  // the servo adopted the offered layout
                mOffered = nullptr;
                mLastStep = mSec->contactNodes[0] - old->contactNodes[0];
                delete old;
            }
            if (mOffered != nullptr || mStalled.load(std::memory_order_acquire)) {
                std::this_thread::sleep_for(std::chrono::microseconds(50));
                continue;
            }
            if (collectBuild()) continue;
            const int want = mChannel.requested.load(std::memory_order_acquire);
            const bool idle = mBuildState.load(std::memory_order_acquire) == kIdle;
            if (mChannel.wanted(*mSec, want)) {
                if (offerCached(want)) continue;
                if (idle) startBuild(want, false);
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
        if (mBuilderThread.joinable()) mBuilderThread.join();
    });
}

bool SecondaryThread::collectBuild() {
    // A finished build: add the entry state from the latest solution and offer it to the servo.
    const int state = mBuildState.load(std::memory_order_acquire);
    if (state != kBuilt && state != kFailed) return false;
    mBuilderThread.join();
    mBuildState.store(kIdle, std::memory_order_relaxed);
    const int want = mChannel.requested.load(std::memory_order_acquire);
    if (state == kBuilt && mBuilt == nullptr) {
        // A prefetch the capacitance secondary cannot give (e.g. a contact at the face's
        // edge, whose primary leaves the zone): not prefetched again; a request for it builds
        // and factorises it then.
        mFailed.push_back(mBuilding);
    } else if (state == kBuilt) {
        if (mBuilding == want && mChannel.wanted(*mSec, want)) {
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

bool SecondaryThread::offerCached(int want) {
    for (std::size_t i = 0; i < mCache.size(); ++i) {
        if (mCache[i]->contactNodes[0] != want) continue;
        std::unique_ptr<Layout> next = std::move(mCache[i]);
        mCache.erase(mCache.begin() + static_cast<std::ptrdiff_t>(i));
        mBuildBegin = std::chrono::steady_clock::now();
        offer(std::move(next));
        return true;
    }
    return false;
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
    if (mLastStep != 0)
        add(c + mLastStep >= 0 && c + mLastStep < mesh.nodeCount() ? c + mLastStep : -1);
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
    const int seeds = mSec->seeds;
    mBuilderThread = std::thread([this, want, seeds, prefetch] {
        // The secondary's CPU and priority: a sliding contact needs its next layout within a
        // node's travel (~100 ms). At nice 10 a 40 ms build took over a second on a core
        // shared with other work, and the contact left the primary.
        nameCurrentThread("palp-layout");
        try {
            // A prefetch never factorises: that would hold the builder for seconds while the
            // contact moves on to a node whose layout is milliseconds.
            mBuilt = mBuilder.buildPrepared(want, seeds, prefetch);
            mBuildState.store(kBuilt, std::memory_order_release);
        } catch (...) {
            mBuildState.store(kFailed, std::memory_order_release);
        }
    });
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
