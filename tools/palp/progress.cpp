#include "progress.h"

#include <unistd.h>

#include <atomic>
#include <csignal>
#include <cstdio>

#include "commands.h"

namespace palp::tool {

namespace {
bool gDrawn = false;
volatile std::sig_atomic_t gSignal = 0;
struct sigaction gOldInt {
}, gOldTerm{};

void onProgressInterrupt(int sig) {
    gSignal = sig;
    // A second Ctrl-C kills as it used to.
    std::signal(sig, SIG_DFL);
}
}  // namespace

InterruptGuard::InterruptGuard() {
    gSignal = 0;
    struct sigaction sa {};
    sa.sa_handler = onProgressInterrupt;
    sigemptyset(&sa.sa_mask);
    sigaction(SIGINT, &sa, &gOldInt);
    sigaction(SIGTERM, &sa, &gOldTerm);
}

InterruptGuard::~InterruptGuard() {
    sigaction(SIGINT, &gOldInt, nullptr);
    sigaction(SIGTERM, &gOldTerm, nullptr);
}

bool InterruptGuard::interrupted() noexcept { return gSignal != 0; }
int InterruptGuard::signal() noexcept { return gSignal; }

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
