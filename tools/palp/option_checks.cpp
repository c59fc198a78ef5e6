#include "option_checks.h"

#include <cerrno>
#include <cmath>
#include <cstdlib>
#include <string>

#include "palp/base/validate.h"

namespace palp::tool {

namespace {

std::string shownText(const std::string& text) {
    return text.empty() ? std::string("an empty value") : "'" + text + "'";
}

}  // namespace

CLI::Validator within(const Bounds& b, DisplayUnit display) {
    const double scale = display.unit.empty() ? 1 : display.scale;
    std::string expected = "expected " + describe(b, display);
    return CLI::Validator(
        [b, scale, expected](std::string& text) -> std::string {
            const char* begin = text.c_str();
            char* end = nullptr;
            errno = 0;
            const double v = std::strtod(begin, &end);
            if (text.empty() || end == begin || *end != '\0')
                return expected + ", found " + shownText(text);
            // Overflow (1e999) reads as inf, which the bounds refuse.
            if (!b.contains(v / scale)) return expected + ", found " + formatValue(v);
            return {};
        },
        describe(b, display));
}

CLI::Validator integerIn(std::int64_t lo, std::int64_t hi) {
    std::string expected =
        "expected an integer in [" + std::to_string(lo) + ", " + std::to_string(hi) + "]";
    return CLI::Validator(
        [lo, hi, expected](std::string& text) -> std::string {
            const char* begin = text.c_str();
            char* end = nullptr;
            errno = 0;
            const long long v = std::strtoll(begin, &end, 10);
            if (text.empty() || end == begin || *end != '\0' || errno == ERANGE || v < lo || v > hi)
                return expected + ", found " + shownText(text);
            return {};
        },
        "INT in [" + std::to_string(lo) + ", " + std::to_string(hi) + "]");
}

void refuseEmptyValues(CLI::App& app) {
    const CLI::Validator nonEmpty(
        [](std::string& text) -> std::string {
            return text.empty() ? "expected a value, found an empty one" : std::string();
        },
        "");
    for (CLI::Option* opt : app.get_options()) {
        if (opt->get_type_size_max() > 0 && opt->get_items_expected_max() > 0) opt->check(nonEmpty);
    }
    for (CLI::App* sub : app.get_subcommands({})) refuseEmptyValues(*sub);
}

}  // namespace palp::tool
