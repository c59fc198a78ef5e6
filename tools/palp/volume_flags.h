#pragma once
// The tool's words for the volume library's choices. Library messages speak of a "time point"
// and a "series UID" (a C or Python caller has no flags); palp's users choose those with
// --volume and --series, so the tool adds the flag to the message.

#include <string>
#include <utility>

#include "palp/base/error.h"

namespace palp::tool {

/// Runs @p read (a load() or readStack() call) and returns its result. A ValueError that asks for
/// a time point or a series is rethrown with the flag that gives it.
template <typename Read>
auto withVolumeFlags(Read&& read) -> decltype(std::forward<Read>(read)()) {
    try {
        return std::forward<Read>(read)();
    } catch (const ValueError& e) {
        std::string message = e.what();
        if (message.find("time point") != std::string::npos) {
            message += "\n(choose the time point with --volume N)";
        } else if (message.find("series UID") != std::string::npos) {
            message += "\n(choose the series with --series UID)";
        } else {
            throw;
        }
        throw ValueError(message);
    }
}

}  // namespace palp::tool
