#include "time_point.h"

#include "palp/base/error.h"

namespace palp::volume::detail {

int chooseTimePoint(std::int64_t count, const ReadOptions& options, const std::string& item) {
    if (count <= 1) {
        if (options.timePoint && *options.timePoint != 0) {
            throw ValueError(item +
                             ": expected time point 0 for a source with one time point, found " +
                             std::to_string(*options.timePoint));
        }
        return -1;
    }
    const std::string choice = "a time point to choose one of the " + std::to_string(count) +
                               " time points (0-" + std::to_string(count - 1) + ")";
    if (!options.timePoint) throw ValueError(item + ": expected " + choice + ", found none");
    if (*options.timePoint < 0 || *options.timePoint >= count) {
        throw ValueError(item + ": expected " + choice + ", found " +
                         std::to_string(*options.timePoint));
    }
    return *options.timePoint;
}

}  // namespace palp::volume::detail
