#pragma once
/// @file
/// A terminal progress line for long work; silent when stderr is not a terminal or --quiet.

#include <string>

#include "palp/volume/resample.h"

namespace palp::tool {

/// Returns a ProgressFn that redraws "label  NN%" on stderr when it is a terminal.
palp::volume::ProgressFn progressLine(const std::string& label);
/// Ends a progress line (newline) if one was drawn.
void endProgress();

}  // namespace palp::tool
