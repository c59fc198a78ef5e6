#pragma once
/// @file
/// A terminal progress line for long work; silent when stderr is not a terminal or --quiet.

#include <string>

#include "palp/volume/resample_options.h"

namespace palp::tool {

/// Returns a ProgressFn that redraws "label  NN%" on stderr when it is a terminal.
palp::volume::ProgressFn progressLine(const std::string& label);
/// Ends a progress line (newline) if one was drawn.
void endProgress();

/// While alive, SIGINT (Ctrl-C) and SIGTERM set a flag instead of killing the process, so a
/// long run can stop between ticks and still write what it has; a second signal kills as
/// before (the outputs are written atomically: whole or not at all). Restores the previous
/// handlers on destruction.
class InterruptGuard {
  public:
    InterruptGuard();
    ~InterruptGuard();
    InterruptGuard(const InterruptGuard&) = delete;
    InterruptGuard& operator=(const InterruptGuard&) = delete;
    /// Whether a signal came since construction.
    static bool interrupted() noexcept;
    /// The signal that came (SIGINT or SIGTERM), 0 for none.
    static int signal() noexcept;
};

}  // namespace palp::tool
