#include <gtest/gtest.h>

#include <cstdint>
#include <thread>

#include "alloc_counter.h"
#include "palp/base/spsc_queue.h"

namespace palp {
namespace {

TEST(SpscQueue, FifoAndCapacity) {
    SpscQueue<int, 4> q;
    EXPECT_TRUE(q.empty());
    EXPECT_EQ(q.capacity(), 4u);
    for (int i = 0; i < 4; ++i) EXPECT_TRUE(q.tryPush(i));
    EXPECT_FALSE(q.tryPush(99));  // full
    EXPECT_EQ(q.size(), 4u);
    int v = -1;
    EXPECT_TRUE(q.tryPop(v));
    EXPECT_EQ(v, 0);
    EXPECT_TRUE(q.tryPush(4));  // wraps around
    for (int i = 1; i <= 4; ++i) {
        ASSERT_TRUE(q.tryPop(v));
        EXPECT_EQ(v, i);
    }
    v = -7;
    EXPECT_FALSE(q.tryPop(v));
    EXPECT_EQ(v, -7);  // untouched when empty
    EXPECT_TRUE(q.empty());
}

TEST(SpscQueue, PushPopDoNotAllocate) {
    SpscQueue<double, 8> q;
    double sum = 0.0;
    const std::uint64_t before = test::allocationCount();
    for (int i = 0; i < 1000; ++i) {
        q.tryPush(i);
        double v = 0.0;
        if (q.tryPop(v)) sum += v;
    }
    EXPECT_EQ(test::allocationCount(), before);
    EXPECT_EQ(sum, 999.0 * 1000.0 / 2.0);
}

struct Command {
    std::uint64_t seq = 0;
    std::uint64_t check = 0;  // a function of seq, to catch torn slots
};

// Give the other side a chance on a loaded machine (outcome does not depend on timing).
void backOff() { std::this_thread::yield(); }

TEST(SpscQueue, TwoThreadStressKeepsOrderAndCompleteness) {
    constexpr std::uint64_t kCount = 50000;
    SpscQueue<Command, 256> q;  // small enough that both full and empty are hit
    std::thread producer([&q] {
        for (std::uint64_t i = 0; i < kCount; ++i) {
            const Command c{i, i * 2654435761u + 1};
            while (!q.tryPush(c)) backOff();
        }
    });
    std::uint64_t expected = 0;
    std::uint64_t bad = 0;
    while (expected < kCount) {
        Command c;
        if (!q.tryPop(c)) {
            backOff();
            continue;
        }
        if (c.seq != expected || c.check != c.seq * 2654435761u + 1) ++bad;
        expected = c.seq + 1;
    }
    producer.join();
    EXPECT_EQ(bad, 0u);
    EXPECT_EQ(expected, kCount);
    EXPECT_TRUE(q.empty());
}

}  // namespace
}  // namespace palp
