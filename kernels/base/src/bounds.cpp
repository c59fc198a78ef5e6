#include "palp/base/bounds.h"

#include "palp/base/validate.h"

namespace palp {

std::string describe(const Bounds& b, DisplayUnit display) {
    // An empty display unit means SI: the bounds' own unit, unscaled.
    const double scale = display.unit.empty() ? 1 : display.scale;
    const std::string_view unit = display.unit.empty() ? b.unit : display.unit;
    std::string s = "a value in ";
    s += b.minOpen ? '(' : '[';
    s += formatValue(b.min * scale);
    s += ", ";
    s += formatValue(b.max * scale);
    s += b.maxOpen ? ')' : ']';
    if (!unit.empty()) {
        s += ' ';
        s += unit;
    }
    return s;
}

void requireWithin(std::string_view what, double v, const Bounds& b) {
    requireWithin(what, v, b, DisplayUnit{});
}

void requireWithin(std::string_view what, double v, const Bounds& b, DisplayUnit display) {
    if (b.contains(v)) return;
    const double scale = display.unit.empty() ? 1 : display.scale;
    throwExpected(what, describe(b, display), formatValue(v * scale));
}

}  // namespace palp
