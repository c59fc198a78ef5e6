#pragma once
/// @file
/// The checks every option of the palp command goes through at parse time, before any work: a
/// number option's text must be a number (not empty, nothing after it), finite and inside the
/// quantity's bounds (palp/base/bounds.h, shown in the option's own unit); an integer option's
/// text an integer in its range; no option that takes a value may be given an empty one. A
/// refusal is a CLI::ValidationError `<option>: expected ..., found ...`; main() prints it as
/// `palp: error: ...` and exits 1.

#include <CLI/CLI.hpp>
#include <cstdint>
#include <string>
#include <utility>

#include "palp/base/bounds.h"
#include "palp/base/error.h"

namespace palp::tool {

/// mm on the command line, m in palp.
inline constexpr DisplayUnit kMm{1e3, "mm"};
/// Degrees on the command line, radians in palp.
inline constexpr DisplayUnit kDegrees{57.29577951308232, "degrees"};

/// A number inside @p b (SI units) as the user types it in @p display (empty: SI).
CLI::Validator within(const Bounds& b, DisplayUnit display = {});
/// An integer in [@p lo, @p hi].
CLI::Validator integerIn(std::int64_t lo, std::int64_t hi);
/// Adds a refusal of empty text to every option of @p app and of its subcommands (recursively)
/// that takes a value. Call after every option is registered.
void refuseEmptyValues(CLI::App& app);

/// Runs @p make(); a palp::IoError or palp::ValueError whose message starts with the library's
/// name for a field (@p field, e.g. "udp device listen address") is thrown again, of the same
/// type, starting with the option that set it (@p option, e.g. "--listen") instead.
template <class Make>
void namingOption(const std::string& field, const std::string& option, Make&& make) {
    const auto renamed = [&](const Error& e) {
        std::string what = e.what();
        if (what.rfind(field, 0) == 0) what = option + what.substr(field.size());
        return what;
    };
    try {
        std::forward<Make>(make)();
    } catch (const IoError& e) {
        throw IoError(renamed(e));
    } catch (const ValueError& e) {
        throw ValueError(renamed(e));
    }
}

}  // namespace palp::tool
