#pragma once
/// @file
/// PALP_CHECK and PALP_DCHECK: invariants that, when broken, mean a bug in palp (never bad
/// input: input is validated and reported through palp::Error). A failed check prints the
/// condition, file and line to stderr and aborts.
///
/// PALP_CHECK is always on: use it where the cost is negligible (set-up, once per frame).
/// PALP_DCHECK is compiled out when NDEBUG is defined (Release): use it in hot loops and on the
/// servo path, where a Debug or sanitizer build should still catch the bug.
/// Both are noexcept and allocation-free, so they may stand in real-time code.

namespace palp::detail {
[[noreturn]] void checkFailed(const char* condition, const char* file, int line) noexcept;
}  // namespace palp::detail

#define PALP_CHECK(condition)           \
    ((condition) ? static_cast<void>(0) \
                 : ::palp::detail::checkFailed(#condition, __FILE__, __LINE__))

#ifdef NDEBUG
#define PALP_DCHECK(condition) static_cast<void>(sizeof(static_cast<bool>(condition)))
#else
#define PALP_DCHECK(condition) PALP_CHECK(condition)
#endif
