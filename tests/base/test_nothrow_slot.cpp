#include <gtest/gtest.h>

#include <cstdint>
#include <type_traits>
#include <vector>

#include "alloc_counter.h"
#include "palp/base/nothrow_slot.h"
#include "palp/base/triple_buffer.h"

namespace palp {
namespace {

struct Packet {
    std::vector<double> values;  // copy assignment is not noexcept
    int tick = 0;
};
static_assert(!std::is_nothrow_copy_assignable_v<Packet>);
static_assert(std::is_nothrow_copy_assignable_v<NothrowSlot<Packet>>);

TEST(NothrowSlot, CarriesPreallocatedValuesThroughATripleBufferWithoutAllocating) {
    const Packet initial{std::vector<double>(16, 0.0), 0};
    TripleBuffer<NothrowSlot<Packet>> exchange{NothrowSlot<Packet>(initial)};
    const std::uint64_t before = test::allocationCount();
    for (int tick = 1; tick <= 100; ++tick) {
        Packet& back = exchange.back().value;
        back.values.assign(16, tick * 0.5);  // same size: reuses the slot's capacity
        back.tick = tick;
        exchange.publish();
    }
    const Packet& got = exchange.read().value;
    EXPECT_EQ(test::allocationCount(), before);
    EXPECT_EQ(got.tick, 100);
    ASSERT_EQ(got.values.size(), 16u);
    EXPECT_EQ(got.values[7], 50.0);
}

}  // namespace
}  // namespace palp
