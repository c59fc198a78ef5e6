#include "palp/base/validate.h"

#include <cmath>
#include <cstdio>

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

}  // namespace palp
