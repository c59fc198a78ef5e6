#pragma once
/// @file
/// Lock-free single-producer single-consumer rings: SpscQueue (capacity fixed at compile time,
/// inline storage: commands from the application to the servo thread) and SpscRing (capacity
/// chosen at run time, storage allocated once: the session's trace of every tick). Both are the
/// one ring below (detail::SpscCore) over two kinds of storage.

#include <array>
#include <atomic>
#include <bit>
#include <cstddef>
#include <cstdint>
#include <type_traits>
#include <utility>
#include <vector>

namespace palp {

namespace detail {

/// The ring's index logic over a power-of-two number of slots that @p Slots provides
/// (`T* data()`, `std::size_t count()`; a count of 0 means a ring that refuses every push).
template <typename T, typename Slots>
class SpscCore {
    static_assert(std::is_nothrow_copy_assignable_v<T> && std::is_default_constructible_v<T>,
                  "SPSC rings hold default-constructible, nothrow-copyable values");

  public:
    /// Producer: appends @p value; false (and nothing stored) when the ring is full or has no
    /// slots.
    bool tryPush(const T& value) noexcept {
        const std::size_t count = mSlots.count();
        if (count == 0) return false;
        const std::size_t tail = mTail.load(std::memory_order_relaxed);
        // Acquire pairs with the consumer's release of mHead: the slot is free to overwrite.
        if (tail - mHead.load(std::memory_order_acquire) == count) return false;
        mSlots.data()[tail & (count - 1)] = value;
        // Release publishes the slot's content before the new tail becomes visible.
        mTail.store(tail + 1, std::memory_order_release);
        return true;
    }

    /// Consumer: moves the oldest value into @p out; false (out untouched) when empty.
    bool tryPop(T& out) noexcept {
        const std::size_t count = mSlots.count();
        if (count == 0) return false;
        const std::size_t head = mHead.load(std::memory_order_relaxed);
        // Acquire pairs with the producer's release of mTail: the slot's content is visible.
        if (head == mTail.load(std::memory_order_acquire)) return false;
        out = mSlots.data()[head & (count - 1)];
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

  protected:
    template <typename... Args>
    explicit SpscCore(Args&&... args) : mSlots(std::forward<Args>(args)...) {}
    std::size_t slotCount() const noexcept { return mSlots.count(); }

  private:
    static constexpr std::size_t kCacheLine = 64;

    // Monotonic counters (wrap-around of size_t is harmless: only differences are used).
    // Each on its own cache line so producer and consumer do not false-share.
    alignas(kCacheLine) std::atomic<std::size_t> mHead{0};  // written by the consumer only
    alignas(kCacheLine) std::atomic<std::size_t> mTail{0};  // written by the producer only
    alignas(kCacheLine) Slots mSlots;
};

template <typename T, std::size_t N>
struct InlineSlots {
    std::array<T, N> slots{};
    T* data() noexcept { return slots.data(); }
    static constexpr std::size_t count() noexcept { return N; }
};

template <typename T>
struct HeapSlots {
    explicit HeapSlots(std::uint32_t capacity)
        : slots(capacity == 0 ? 0 : std::bit_ceil(capacity)) {}
    std::vector<T> slots;
    T* data() noexcept { return slots.data(); }
    std::size_t count() const noexcept { return slots.size(); }
};

}  // namespace detail

/// A ring of @p Capacity slots (a power of two) that one producer thread fills and one consumer
/// thread drains, in order. Storage is inline: no allocation after construction.
///
/// @par Threading
/// Exactly one thread may call tryPush() and exactly one (other) thread tryPop(); size() and
/// empty() may be called from either and are approximate while the other side runs.
/// @par Real-time
/// tryPush() and tryPop() are wait-free, noexcept (for nothrow-copyable T) and allocation-free.
template <typename T, std::size_t Capacity>
class SpscQueue : public detail::SpscCore<T, detail::InlineSlots<T, Capacity>> {
    static_assert(Capacity > 0 && (Capacity & (Capacity - 1)) == 0,
                  "SpscQueue capacity must be a power of two");

  public:
    SpscQueue() = default;
    /// Maximum number of queued values.
    static constexpr std::size_t capacity() noexcept { return Capacity; }
};

/// The same ring with capacity() slots chosen at run time: the requested capacity rounded up
/// to a power of two (at most 2^31); 0 gives a ring with no slots, whose every tryPush() fails.
/// Storage is allocated once, in the constructor.
///
/// @par Threading  As SpscQueue.
/// @par Real-time  tryPush() and tryPop() are wait-free, noexcept and allocation-free; the
/// constructor allocates (set-up only).
template <typename T>
class SpscRing : public detail::SpscCore<T, detail::HeapSlots<T>> {
  public:
    /// @throw std::bad_alloc
    explicit SpscRing(std::uint32_t capacity)
        : detail::SpscCore<T, detail::HeapSlots<T>>(capacity) {}
    /// Maximum number of queued values (0: the ring has no slots).
    std::size_t capacity() const noexcept { return this->slotCount(); }
};

}  // namespace palp
