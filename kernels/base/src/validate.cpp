#include "palp/base/validate.h"

#include <cmath>
#include <cstdio>
#include <exception>
#include <string>

#include "palp/base/error.h"

namespace palp {

namespace {

std::string requirement(std::string_view text, std::string_view unit) {
    std::string s(text);
    if (!unit.empty()) {
        s += ' ';
        s += unit;
    }
    return s;
}

}  // namespace

std::string formatValue(double v) {
    char buf[32];
    std::snprintf(buf, sizeof buf, "%g", v);
    return buf;
}

void throwExpected(std::string_view what, std::string_view expected, std::string_view found) {
    std::string msg(what);
    msg += ": expected ";
    msg += expected;
    msg += ", found ";
    msg += found;
    throw ValueError(msg);
}

void requireFinite(std::string_view what, double v, std::string_view unit) {
    if (!std::isfinite(v)) throwExpected(what, requirement("a finite value", unit), formatValue(v));
}

void requirePositive(std::string_view what, double v, std::string_view unit) {
    if (!(std::isfinite(v) && v > 0))
        throwExpected(what, requirement("a finite value > 0", unit), formatValue(v));
}

void requireNonNegative(std::string_view what, double v, std::string_view unit) {
    if (!(std::isfinite(v) && v >= 0))
        throwExpected(what, requirement("a finite value >= 0", unit), formatValue(v));
}

void requireAtLeast(std::string_view what, double v, double min, std::string_view unit) {
    if (!(std::isfinite(v) && v >= min))
        throwExpected(what, requirement("a finite value >= " + formatValue(min), unit),
                      formatValue(v));
}

void requireInRange(std::string_view what, double v, double lo, double hi, std::string_view unit) {
    if (!(std::isfinite(v) && v >= lo && v <= hi))
        throwExpected(
            what,
            requirement("a value in [" + formatValue(lo) + ", " + formatValue(hi) + "]", unit),
            formatValue(v));
}

std::pair<std::int64_t, std::int64_t> parseShard(const std::string& text) {
    const auto slash = text.find('/');
    std::int64_t i = -1, n = -1;
    try {
        std::size_t a = 0, b = 0;
        if (slash != std::string::npos) {
            i = std::stoll(text.substr(0, slash), &a);
            n = std::stoll(text.substr(slash + 1), &b);
            if (a != slash || b != text.size() - slash - 1) i = n = -1;
        }
    } catch (const std::exception&) {
        i = n = -1;
    }
    if (n < 1 || i < 0 || i >= n)
        throw ValueError(
            "--shard: expected i/n with integers 0 <= i < n (e.g. "
            "$SLURM_ARRAY_TASK_ID/$SLURM_ARRAY_TASK_COUNT), found '" +
            text + "'");
    return {i, n};
}

}  // namespace palp
