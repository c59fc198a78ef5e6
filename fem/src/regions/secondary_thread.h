#pragma once
/// @file
/// SecondaryThread: the thread that runs the secondary region in threaded mode, and
/// LayoutChannel, the hand-over of layouts for contact changes between it and the servo.

#include <tbb/task_arena.h>

#include <array>
#include <atomic>
#include <chrono>
#include <condition_variable>
#include <memory>
#include <mutex>
#include <thread>
#include <vector>

#include "regions/async_layout.h"
#include "regions/async_setup.h"
#include "regions/layout_builder.h"
#include "regions/secondary_region.h"

namespace palp::fem {

/// Contact changes: the servo stores the requested node; the preparer (the secondary thread, or
/// the synchronous period boundary) prepares a layout for it and publishes it in `pending`; the
/// servo adopts it with one pointer exchange and hands the layout it replaced back in `retired`
/// for deletion on the secondary thread.
/// @par Threading  requested: servo -> preparer; pending: preparer -> servo; retired: servo ->
/// secondary (acquire/release pointer exchanges transfer ownership of the Layout). rejected is
/// the preparer's own.
struct LayoutChannel {
    LayoutChannel() = default;
    LayoutChannel(const LayoutChannel&) = delete;
    LayoutChannel& operator=(const LayoutChannel&) = delete;
    /// Deletes a layout still in flight (after the secondary thread has stopped).
    ~LayoutChannel();
    /// Whether node @p want asks for a change from @p L's contact (and was not rejected before).
    bool wanted(const Layout& L, int want) const noexcept;

    std::atomic<int> requested{-1};
    std::atomic<Layout*> pending{nullptr};  // prepared, not yet adopted
    std::atomic<Layout*> retired{nullptr};  // adopted over, to delete
    int rejected = -1;                      // a request that failed to build
};

/// Runs the secondary region on its own thread (pinned per options, named "palp-secondary"),
/// inside the secondary's task_arena: reads border snapshots, solves, publishes results, and
/// prepares layouts for contact changes (a builder thread, started by it and so on the same CPU
/// and priority, living as long as it, builds and factorises while this thread keeps solving;
/// this thread then adds the entry state from its latest solution and offers the layout to the
/// servo).
/// @par Threading  Constructed and destroyed by the servo's owner (the destructor stops and joins
/// the thread). The thread owns the SecondaryRegion and the secondary work state of the layout in
/// use; with the servo it shares only the two triple buffers of @p exchange, the LayoutChannel and
/// the stall / stop flags. A stalled or slow secondary never blocks the servo.
class SecondaryThread {
  public:
    /// Starts the thread on @p initial (the servo's current layout). Every argument must outlive
    /// the object.
    SecondaryThread(const AsyncSetup& setup, const LayoutBuilder& builder,
                    SecondaryRegion& secondary, BorderExchange& exchange, LayoutChannel& channel,
                    Layout& initial, tbb::task_arena& arena);
    ~SecondaryThread();
    SecondaryThread(const SecondaryThread&) = delete;
    SecondaryThread& operator=(const SecondaryThread&) = delete;

    /// Test hook: while true the thread neither reads snapshots nor publishes. Any thread.
    void setStalled(bool stalled) noexcept { mStalled.store(stalled, std::memory_order_release); }
    /// Test hook: builds take at least @p seconds more. Any thread.
    void setBuildDelay(double seconds) noexcept {
        mBuildDelay.store(seconds, std::memory_order_release);
    }

  private:
    enum BuildState : int { kIdle, kBuilding, kBuilt, kFailed };

    void run();
    // The builder thread: waits for a posted request, builds it, publishes mBuildState.
    void buildLoop();
    bool collectBuild();
    void startBuild(int want, bool prefetch);
    bool offerCached(int want);
    int latticeStep(int from, int to) const;
    // Gives the heap's free pages back to the system (glibc), at most once a second.
    void trimHeap();
    void track(int want);
    int ahead(int want) const;
    double distance2(int a, int b) const;
    bool nearer(int node, int want) const;
    void offer(std::unique_ptr<Layout> next);
    void prefetch();
    void solveSnapshot(const BorderPacket& in);

    const AsyncSetup& mSetup;
    const LayoutBuilder& mBuilder;
    SecondaryRegion& mSecondary;
    BorderExchange& mExchange;
    LayoutChannel& mChannel;
    tbb::task_arena& mArena;
    // Secondary-thread state: the layout the servo uses (or will, once it adopts mOffered).
    Layout* mSec;
    Layout* mOffered = nullptr;
    int mBuilding = -1;
    std::chrono::steady_clock::time_point mBuildBegin;
    // Builder thread: writes mBuilt, then releases mBuildState (kBuilt or kFailed).
    std::atomic<int> mBuildState{kIdle};
    std::unique_ptr<Layout> mBuilt;
    // Prefetch (capacitance secondary, where a layout is milliseconds): layouts for the slide
    // neighbours of the current contact, built while no change is asked for, so a request for
    // one is offered at once with only its entry state added.
    std::vector<std::unique_ptr<Layout>> mCache;
    std::vector<int> mFailed;  // nodes whose build failed (not prefetched again)
    std::chrono::steady_clock::time_point mLastTrim{};  // trimHeap()'s last trim
    int mLastStep = 0;  // one lattice edge along the last contact change (prefetched first)
    // The requested nodes of late (a ring), for building ahead of a sliding contact, and the
    // recent build time (moving average, seconds).
    struct TrackPoint {
        std::chrono::steady_clock::time_point time;
        int node = -1;
    };
    static constexpr std::size_t kTrack = 16;
    std::array<TrackPoint, kTrack> mTrack{};
    std::size_t mTrackCount = 0;
    double mBuildSeconds = 0;
    // The request posted to the builder (under mBuildMutex; mPosted until it takes it).
    struct BuildRequest {
        int node = -1, seeds = 0;
        bool prefetch = false;
    };
    std::mutex mBuildMutex;
    std::condition_variable mBuildWake;
    BuildRequest mRequest;
    bool mPosted = false, mBuilderStop = false;
    std::thread mBuilderThread;  // started by run(), joined at its end
    std::atomic<bool> mStop{false}, mStalled{false};
    std::atomic<double> mBuildDelay{0.0};
    std::thread mWorker;  // last: started when everything above is set
};

}  // namespace palp::fem
