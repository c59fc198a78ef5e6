#include "progress.h"

#include <unistd.h>

#include <cstdio>

#include "commands.h"

namespace palp::tool {

namespace {
bool gDrawn = false;
}

palp::volume::ProgressFn progressLine(const std::string& label) {
    if (globals().quiet || !::isatty(STDERR_FILENO)) return {};
    return [label, last = -1](double f) mutable {
        const int pct = static_cast<int>(f * 100.0);
        if (pct != last) {
            std::fprintf(stderr, "\r%s %3d%%", label.c_str(), pct);
            std::fflush(stderr);
            last = pct;
            gDrawn = true;
        }
        return true;
    };
}

void endProgress() {
    if (gDrawn) std::fputc('\n', stderr);
    gDrawn = false;
}

}  // namespace palp::tool
