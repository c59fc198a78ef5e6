#include "secondary_thread.h"

#include <sys/resource.h>
#include <unistd.h>

#include <algorithm>

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
                delete old;
            }
            if (mOffered != nullptr || mStalled.load(std::memory_order_acquire)) {
                std::this_thread::sleep_for(std::chrono::microseconds(50));
                continue;
            }
            if (collectBuild()) continue;
            const int want = mChannel.requested.load(std::memory_order_acquire);
            if (mBuildState.load(std::memory_order_acquire) == kIdle &&
                mChannel.wanted(*mSec, want))
                startBuild(want);
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
    if (state == kBuilt) {
        try {
            mSecondary.prepareEntry(*mSec, *mBuilt, mBuildBegin);
            mOffered = mBuilt.release();
            mChannel.pending.store(mOffered, std::memory_order_release);
        } catch (...) {
            mChannel.rejected = mBuilding;
        }
    } else {
        mChannel.rejected = mBuilding;  // e.g. a failed factorisation: keep the current layout
    }
    mBuilt.reset();
    return true;
}

void SecondaryThread::startBuild(int want) {
    mBuilding = want;
    mBuildBegin = std::chrono::steady_clock::now();
    mBuildState.store(kBuilding, std::memory_order_relaxed);
    const int seeds = mSec->seeds;
    mBuilderThread = std::thread([this, want, seeds] {
        nameCurrentThread("palp-layout");
        setpriority(PRIO_PROCESS, static_cast<id_t>(gettid()), 10);
        try {
            mBuilt = mBuilder.buildPrepared(want, seeds);
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
