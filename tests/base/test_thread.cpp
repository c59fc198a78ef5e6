#include <gtest/gtest.h>
#include <pthread.h>
#include <sched.h>

#include <atomic>
#include <cerrno>
#include <chrono>
#include <thread>

#include "palp/base/thread.h"

namespace palp {
namespace {

TEST(Thread, CpuListTextIsCompact) {
    EXPECT_EQ(cpuListText({}), "none");
    EXPECT_EQ(cpuListText({3}), "3");
    EXPECT_EQ(cpuListText({0, 1, 2, 3, 6}), "0-3,6");
    EXPECT_EQ(cpuListText({0, 2, 4, 5}), "0,2,4-5");
}

TEST(Thread, PinningMovesTheThreadToThatCpuAndCanBeUndone) {
    const std::vector<int> cpus = allowedCpus();
    ASSERT_FALSE(cpus.empty());
    std::thread t([&] {
        ASSERT_EQ(pinCurrentThread(cpus.back()), 0);
        EXPECT_EQ(allowedCpus(), std::vector<int>{cpus.back()});
        EXPECT_EQ(sched_getcpu(), cpus.back());
        ASSERT_EQ(setCurrentThreadCpus(cpus), 0);
        EXPECT_EQ(allowedCpus(), cpus);
    });
    t.join();
}

TEST(Thread, BadRequestsReturnAnErrorNumberAndChangeNothing) {
    const std::vector<int> before = allowedCpus();
    EXPECT_EQ(pinCurrentThread(-1), EINVAL);
    EXPECT_EQ(setCurrentThreadCpus({}), EINVAL);
    EXPECT_NE(pinCurrentThread(100000), 0);  // beyond any CPU of this machine
    EXPECT_EQ(allowedCpus(), before);
    EXPECT_EQ(setCurrentThreadFifo(0), EINVAL);  // SCHED_FIFO priorities are 1-99
}

TEST(Thread, NamesAreCutToTheKernelsLimit) {
    std::thread t([] {
        ASSERT_EQ(nameCurrentThread("palp-a-very-long-thread-name"), 0);
        char name[32] = {};
        ASSERT_EQ(pthread_getname_np(pthread_self(), name, sizeof name), 0);
        EXPECT_STREQ(name, "palp-a-very-lon");
    });
    t.join();
    EXPECT_EQ(errorText(EPERM), "Operation not permitted");
}

// A reservation takes the CPU from every other thread whose mask has it and another CPU,
// threads started afterwards inherit the narrower mask, a thread pinned to that CPU alone stays,
// and release() gives everyone back the mask they had (the late thread its parent's).
TEST(Thread, ReservingACpuMovesTheOtherThreadsOffItUntilReleased) {
    const std::vector<int> cpus = allowedCpus();
    if (cpus.size() < 2) GTEST_SKIP() << "one CPU: nothing to move to";
    const int kept = cpus.back();
    std::vector<int> rest(cpus.begin(), cpus.end() - 1);
    std::atomic<int> phase{0};
    std::atomic<bool> pinnedReady{false};
    std::vector<int> workerDuring, workerAfter, lateDuring, lateAfter, pinnedDuring;
    std::thread worker([&] {  // the process's mask, like a TBB worker
        while (phase.load() < 1) std::this_thread::yield();
        workerDuring = allowedCpus();
        std::thread late([&] {  // started while the CPU is reserved
            lateDuring = allowedCpus();
            while (phase.load() < 2) std::this_thread::yield();
            lateAfter = allowedCpus();
        });
        while (phase.load() < 2) std::this_thread::yield();
        late.join();
        workerAfter = allowedCpus();
    });
    std::thread pinned([&] {  // another servo on the same CPU
        EXPECT_EQ(pinCurrentThread(kept), 0);
        pinnedReady = true;
        while (phase.load() < 1) std::this_thread::yield();
        pinnedDuring = allowedCpus();
    });
    std::size_t moved = 0;
    std::vector<int> mainDuring;
    std::thread keeper([&] {
        EXPECT_EQ(pinCurrentThread(kept), 0);
        while (!pinnedReady.load()) std::this_thread::yield();
        CpuReservation r = CpuReservation::reserve(kept);
        moved = r.threadsMoved();
        EXPECT_EQ(r.cpu(), kept);
        phase = 1;
        std::this_thread::sleep_for(std::chrono::milliseconds(50));
        r.release();
        EXPECT_EQ(r.threadsMoved(), 0u);
        r.release();  // idempotent
        phase = 2;
    });
    // The main thread is moved too: read its mask while the keeper holds the CPU.
    while (phase.load() < 1) std::this_thread::yield();
    mainDuring = allowedCpus();
    keeper.join();
    worker.join();
    pinned.join();
    EXPECT_EQ(mainDuring, rest);
    EXPECT_EQ(workerDuring, rest);
    EXPECT_EQ(lateDuring, rest);
    EXPECT_EQ(pinnedDuring, std::vector<int>{kept});
    EXPECT_EQ(workerAfter, cpus);
    EXPECT_EQ(lateAfter, cpus);
    EXPECT_EQ(allowedCpus(), cpus);  // the main thread's mask is back
    EXPECT_GE(moved, 2u);            // the main thread and the worker, at least
}

}  // namespace
}  // namespace palp
