#pragma once
// bench_async's threaded mode (bench_async_slide.cpp), called by its main (bench_async.cpp).
#include "async_problem.h"

namespace palp::fem::bench {

/// Threaded mode: the servo thread pinned to CPU 0 at 1 kHz wall clock, the secondary on CPU 1;
/// with --move a moving contact against the whole mesh.
void threaded(const Config& c);

}  // namespace palp::fem::bench
