#include <gtest/gtest.h>

#include <array>
#include <cstdint>
#include <thread>

#include "alloc_counter.h"
#include "palp/base/triple_buffer.h"

namespace palp {
namespace {

TEST(TripleBuffer, ReaderSeesLatestPublished) {
    TripleBuffer<int> tb(7);
    EXPECT_EQ(tb.read(), 7);  // initial value before any publish
    EXPECT_FALSE(tb.update());
    tb.write(1);
    tb.write(2);
    tb.write(3);
    EXPECT_TRUE(tb.update());
    EXPECT_EQ(tb.front(), 3);  // intermediate values skipped
    EXPECT_FALSE(tb.update());
    EXPECT_EQ(tb.front(), 3);  // stays until something new arrives
    tb.back() = 4;
    tb.publish();
    EXPECT_EQ(tb.read(), 4);
}

TEST(TripleBuffer, WriterNeverTouchesTheFrontSlot) {
    TripleBuffer<int> tb(0);
    tb.write(10);
    const int& front = tb.read();
    for (int i = 0; i < 10; ++i) tb.write(100 + i);  // writer runs ahead
    EXPECT_EQ(front, 10);
    EXPECT_EQ(tb.read(), 109);
}

TEST(TripleBuffer, DoesNotAllocate) {
    TripleBuffer<std::array<double, 16>> tb;
    const std::uint64_t before = test::allocationCount();
    double sum = 0.0;
    for (int i = 0; i < 1000; ++i) {
        tb.back().fill(i);
        tb.publish();
        sum += tb.read()[0];
    }
    EXPECT_EQ(test::allocationCount(), before);
    EXPECT_EQ(sum, 999.0 * 1000.0 / 2.0);
}

// A snapshot large enough that a torn copy would show: every word is a function of seq.
struct Snapshot {
    std::uint64_t seq = 0;
    std::array<std::uint64_t, 15> words{};
};

TEST(TripleBuffer, TwoThreadStressGivesWholeMonotonicSnapshots) {
    constexpr std::uint64_t kCount = 200000;
    TripleBuffer<Snapshot> tb;
    std::thread writer([&tb] {
        for (std::uint64_t s = 1; s <= kCount; ++s) {
            Snapshot& b = tb.back();
            b.seq = s;
            for (std::size_t i = 0; i < b.words.size(); ++i) b.words[i] = s * (i + 3);
            tb.publish();
        }
    });
    std::uint64_t last = 0;
    std::uint64_t torn = 0;
    std::uint64_t backwards = 0;
    std::uint64_t fresh = 0;
    while (last < kCount) {  // the final publish is always delivered
        if (!tb.update()) {
            std::this_thread::yield();
            continue;
        }
        ++fresh;
        const Snapshot& s = tb.front();
        for (std::size_t i = 0; i < s.words.size(); ++i) {
            if (s.words[i] != s.seq * (i + 3)) ++torn;
        }
        if (s.seq <= last) ++backwards;  // each fresh value is strictly newer
        last = s.seq;
    }
    writer.join();
    EXPECT_EQ(torn, 0u);
    EXPECT_EQ(backwards, 0u);
    EXPECT_EQ(last, kCount);
    EXPECT_GE(fresh, 1u);
    EXPECT_FALSE(tb.update());
}

}  // namespace
}  // namespace palp
