#pragma once
/// @file
/// A wrapper that lets a value travel through the lock-free exchanges (TripleBuffer, SpscQueue),
/// which require a nothrow copy assignment, when the value's own copy cannot throw in practice
/// but is not declared noexcept.

namespace palp {

/// Holds a T whose copy assignment is declared noexcept here. For types whose copy cannot throw
/// but is not declared so: Eigen fixed-size matrices, plain structs of them, and structs of
/// containers that are preallocated to equal sizes before use (their copy reuses the capacity).
/// A copy that throws anyway ends the program (std::terminate), as for any noexcept function.
///
/// @par Threading  None of its own: the exchange that holds it decides who owns a slot.
/// @par Real-time  Copying allocates nothing when T's copy allocates nothing.
template <typename T>
struct NothrowSlot {
    T value{};

    NothrowSlot() = default;
    /// Wraps a copy of @p v (e.g. the preallocated initial value of every slot).
    explicit NothrowSlot(const T& v) : value(v) {}
    NothrowSlot(const NothrowSlot&) = default;
    NothrowSlot& operator=(const NothrowSlot& other) noexcept {
        value = other.value;
        return *this;
    }
};

}  // namespace palp
