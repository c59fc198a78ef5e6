#pragma once
/// @file
/// Lock-free latest-value exchange between one writer and one reader (snapshots of the servo
/// state for viewers, border displacements from the secondary solver).

#include <array>
#include <atomic>
#include <cstdint>
#include <type_traits>

namespace palp {

/// Three slots: the writer fills its back slot and publishes it; the reader takes the newest
/// published slot as its front. Neither side ever waits, and the reader always sees a complete
/// value (never one half-written), though it may skip intermediate ones.
///
/// @par Threading
/// Exactly one thread calls write()/back()/publish() and exactly one (other) thread calls
/// update()/read(). The slots are owned in turn: back by the writer, front by the reader, the
/// middle one by whoever last exchanged it.
/// @par Real-time
/// All members are wait-free, noexcept (for nothrow-copyable T) and allocation-free.
template <typename T>
class TripleBuffer {
    static_assert(std::is_nothrow_copy_assignable_v<T>, "TripleBuffer holds nothrow-copyable T");

  public:
    /// All three slots start as @p initial, so read() is valid before the first publish.
    explicit TripleBuffer(const T& initial = T{}) : mSlots{initial, initial, initial} {}

    /// Writer: the slot to fill in place before publish() (avoids a copy of large T).
    T& back() noexcept { return mSlots[mBack]; }

    /// Writer: makes the back slot the newest value and takes a free slot as the new back.
    void publish() noexcept {
        // Release publishes the slot's content; acquire takes ownership of the returned slot
        // after the reader's last use of it.
        const std::uint8_t prev =
            mMiddle.exchange(static_cast<std::uint8_t>(mBack | kFresh), std::memory_order_acq_rel);
        mBack = static_cast<std::uint8_t>(prev & kIndexMask);
    }

    /// Writer: copies @p value into the back slot and publishes it.
    void write(const T& value) noexcept {
        back() = value;
        publish();
    }

    /// Reader: takes the newest published value as the front slot; true when it is new since
    /// the last update().
    bool update() noexcept {
        if ((mMiddle.load(std::memory_order_relaxed) & kFresh) == 0) return false;
        const std::uint8_t prev = mMiddle.exchange(mFront, std::memory_order_acq_rel);
        mFront = static_cast<std::uint8_t>(prev & kIndexMask);
        return true;
    }

    /// Reader: the front slot (valid until the next update()).
    const T& front() const noexcept { return mSlots[mFront]; }

    /// Reader: update() then front().
    const T& read() noexcept {
        update();
        return front();
    }

  private:
    static constexpr std::uint8_t kIndexMask = 0x3;
    static constexpr std::uint8_t kFresh = 0x4;  // middle slot holds an unread value

    std::array<T, 3> mSlots;
    std::uint8_t mBack = 0;                // writer-owned
    std::atomic<std::uint8_t> mMiddle{1};  // shared: index | kFresh
    std::uint8_t mFront = 2;               // reader-owned
};

}  // namespace palp
