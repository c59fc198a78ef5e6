#pragma once
/// @file
/// Fixed-capacity, lock-free, single-producer single-consumer ring (commands from the
/// application to the servo thread, events back).

#include <array>
#include <atomic>
#include <cstddef>
#include <type_traits>

namespace palp {

/// A ring of @p Capacity slots (a power of two) that one producer thread fills and one consumer
/// thread drains, in order. Storage is inline: no allocation after construction.
///
/// @par Threading
/// Exactly one thread may call tryPush() and exactly one (other) thread tryPop(); size() and
/// empty() may be called from either and are approximate while the other side runs.
/// @par Real-time
/// tryPush() and tryPop() are wait-free, noexcept (for nothrow-copyable T) and allocation-free.
template <typename T, std::size_t Capacity>
class SpscQueue {
    static_assert(Capacity > 0 && (Capacity & (Capacity - 1)) == 0,
                  "SpscQueue capacity must be a power of two");
    static_assert(std::is_nothrow_copy_assignable_v<T> && std::is_default_constructible_v<T>,
                  "SpscQueue holds default-constructible, nothrow-copyable values");

  public:
    /// Producer: appends @p value; false (and nothing stored) when the ring is full.
    bool tryPush(const T& value) noexcept {
        const std::size_t tail = mTail.load(std::memory_order_relaxed);
        // Acquire pairs with the consumer's release of mHead: the slot is free to overwrite.
        if (tail - mHead.load(std::memory_order_acquire) == Capacity) return false;
        mSlots[tail & kMask] = value;
        // Release publishes the slot's content before the new tail becomes visible.
        mTail.store(tail + 1, std::memory_order_release);
        return true;
    }

    /// Consumer: moves the oldest value into @p out; false (out untouched) when empty.
    bool tryPop(T& out) noexcept {
        const std::size_t head = mHead.load(std::memory_order_relaxed);
        // Acquire pairs with the producer's release of mTail: the slot's content is visible.
        if (head == mTail.load(std::memory_order_acquire)) return false;
        out = mSlots[head & kMask];
        // Release hands the slot back to the producer only after it has been read.
        mHead.store(head + 1, std::memory_order_release);
        return true;
    }

    /// Number of values queued (a snapshot).
    std::size_t size() const noexcept {
        const std::size_t head = mHead.load(std::memory_order_acquire);
        return mTail.load(std::memory_order_acquire) - head;
    }
    /// True when nothing is queued (a snapshot).
    bool empty() const noexcept { return size() == 0; }
    /// Maximum number of queued values.
    static constexpr std::size_t capacity() noexcept { return Capacity; }

  private:
    static constexpr std::size_t kMask = Capacity - 1;
    static constexpr std::size_t kCacheLine = 64;

    // Monotonic counters (wrap-around of size_t is harmless: only differences are used).
    // Each on its own cache line so producer and consumer do not false-share.
    alignas(kCacheLine) std::atomic<std::size_t> mHead{0};  // written by the consumer only
    alignas(kCacheLine) std::atomic<std::size_t> mTail{0};  // written by the producer only
    alignas(kCacheLine) std::array<T, Capacity> mSlots{};
};

}  // namespace palp
