#pragma once
/// @file
/// Lock-free single-producer single-consumer ring whose capacity is chosen at run time (the
/// session's trace of every tick); SpscQueue (spsc_queue.h) is the same ring with a
/// compile-time capacity and inline storage.

#include <atomic>
#include <bit>
#include <cstddef>
#include <cstdint>
#include <type_traits>
#include <vector>

namespace palp {

/// A ring of capacity() slots (the requested capacity rounded up to a power of two; 0: no
/// slots, every tryPush() fails) that one producer thread fills and one consumer thread
/// drains, in order. Storage is allocated once, in the constructor.
///
/// @par Threading
/// Exactly one thread may call tryPush() and exactly one (other) thread tryPop(); size() and
/// empty() may be called from either and are approximate while the other side runs.
/// @par Real-time
/// tryPush() and tryPop() are wait-free, noexcept and allocation-free.
template <typename T>
class SpscRing {
    static_assert(std::is_nothrow_copy_assignable_v<T> && std::is_default_constructible_v<T>,
                  "SpscRing holds default-constructible, nothrow-copyable values");

  public:
    /// A ring of at least @p capacity slots (rounded up to a power of two; at most 2^31).
    /// @throw std::bad_alloc
    explicit SpscRing(std::uint32_t capacity)
        : mSlots(capacity == 0 ? 0 : std::bit_ceil(capacity)),
          mMask(mSlots.empty() ? 0 : mSlots.size() - 1) {}

    /// Producer: appends @p value; false (and nothing stored) when the ring is full or has no
    /// slots.
    bool tryPush(const T& value) noexcept {
        if (mSlots.empty()) return false;
        const std::size_t tail = mTail.load(std::memory_order_relaxed);
        // Acquire pairs with the consumer's release of mHead: the slot is free to overwrite.
        if (tail - mHead.load(std::memory_order_acquire) == mSlots.size()) return false;
        mSlots[tail & mMask] = value;
        // Release publishes the slot's content before the new tail becomes visible.
        mTail.store(tail + 1, std::memory_order_release);
        return true;
    }

    /// Consumer: moves the oldest value into @p out; false (out untouched) when empty.
    bool tryPop(T& out) noexcept {
        if (mSlots.empty()) return false;
        const std::size_t head = mHead.load(std::memory_order_relaxed);
        // Acquire pairs with the producer's release of mTail: the slot's content is visible.
        if (head == mTail.load(std::memory_order_acquire)) return false;
        out = mSlots[head & mMask];
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
    /// Maximum number of queued values (0: the ring has no slots).
    std::size_t capacity() const noexcept { return mSlots.size(); }

  private:
    static constexpr std::size_t kCacheLine = 64;

    std::vector<T> mSlots;
    std::size_t mMask;
    // Monotonic counters (only differences are used), each on its own cache line.
    alignas(kCacheLine) std::atomic<std::size_t> mHead{0};  // written by the consumer only
    alignas(kCacheLine) std::atomic<std::size_t> mTail{0};  // written by the producer only
};

}  // namespace palp
