#include <gtest/gtest.h>
#include <pthread.h>
#include <sched.h>

#include <cerrno>
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

}  // namespace
}  // namespace palp
