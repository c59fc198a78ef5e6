#include <gtest/gtest.h>

#include <cstdint>
#include <thread>

#include "alloc_counter.h"
#include "palp/base/spsc_queue.h"

namespace palp {
namespace {

TEST(SpscRing, CapacityRoundsUpToAPowerOfTwo) {
    EXPECT_EQ(SpscRing<int>(1).capacity(), 1u);
    EXPECT_EQ(SpscRing<int>(3).capacity(), 4u);
    EXPECT_EQ(SpscRing<int>(4).capacity(), 4u);
    EXPECT_EQ(SpscRing<int>(1000).capacity(), 1024u);
}

TEST(SpscRing, ZeroCapacityRefusesEverything) {
    SpscRing<int> q(0);
    EXPECT_EQ(q.capacity(), 0u);
    EXPECT_FALSE(q.tryPush(1));
    int v = -3;
    EXPECT_FALSE(q.tryPop(v));
    EXPECT_EQ(v, -3);
    EXPECT_TRUE(q.empty());
}

TEST(SpscRing, FifoAndCapacity) {
    SpscRing<int> q(3);  // 4 slots
    EXPECT_TRUE(q.empty());
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

TEST(SpscRing, PushPopDoNotAllocate) {
    SpscRing<double> q(8);
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

struct Item {
    std::uint64_t seq = 0;
    std::uint64_t check = 0;  // a function of seq, to catch torn slots
};

TEST(SpscRing, TwoThreadStressKeepsOrderAndCompleteness) {
    constexpr std::uint64_t kCount = 50000;
    SpscRing<Item> q(200);  // 256 slots: small enough that both full and empty are hit
    std::thread producer([&q] {
        for (std::uint64_t i = 0; i < kCount; ++i) {
            const Item c{i, i * 2654435761u + 1};
            while (!q.tryPush(c)) std::this_thread::yield();
        }
    });
    std::uint64_t expected = 0;
    while (expected < kCount) {
        Item c;
        if (!q.tryPop(c)) {
            std::this_thread::yield();
            continue;
        }
        ASSERT_EQ(c.seq, expected);
        ASSERT_EQ(c.check, c.seq * 2654435761u + 1);
        ++expected;
    }
    producer.join();
    EXPECT_TRUE(q.empty());
}

}  // namespace
}  // namespace palp
