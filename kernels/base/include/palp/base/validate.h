#pragma once
/// @file
/// The "expected ..., found ..." checks shared by every module's set-up and IO code.
///
/// Every helper takes the name of the thing checked first (a field, option or file, as the
/// caller's user knows it), then the value, then what is required, and throws palp::ValueError
/// with the message `<what>: expected <requirement>, found <value>`. Numbers are printed with
/// formatValue() (`%g`: `1e+300`, `nan`, `-inf`), so a message shows the value the user gave.
/// Not for the servo path: these throw.

#include <cstdint>
#include <string>
#include <string_view>
#include <utility>

namespace palp {

/// @p v as `%g` prints it (six significant digits; `nan`, `inf`).
std::string formatValue(double v);

/// Throws ValueError(`<what>: expected <expected>, found <found>`).
[[noreturn]] void throwExpected(std::string_view what, std::string_view expected,
                                std::string_view found);

/// Throws unless @p v is finite. @p unit, when given, follows the requirement ("... in mm").
void requireFinite(std::string_view what, double v, std::string_view unit = {});
/// Throws unless @p v is finite and > 0.
void requirePositive(std::string_view what, double v, std::string_view unit = {});
/// Throws unless @p v is finite and >= 0.
void requireNonNegative(std::string_view what, double v, std::string_view unit = {});
/// Throws unless @p v is finite and >= @p min.
void requireAtLeast(std::string_view what, double v, double min, std::string_view unit = {});
/// Throws unless @p v is finite and in [@p lo, @p hi].
void requireInRange(std::string_view what, double v, double lo, double hi,
                    std::string_view unit = {});

/// Parses "i/n" (as --shard takes it: a job array's task of n) into (i, n).
/// @throw palp::ValueError naming --shard and the text unless 0 <= i < n.
std::pair<std::int64_t, std::int64_t> parseShard(const std::string& text);

}  // namespace palp
