#pragma once
/// @file
/// The heap settings of palp's batch commands (convert, info): a grid of hundreds of MB built or
/// read leaf by leaf in one process that then exits.

namespace palp::tool {

/// Sets glibc's heap for a batch job that allocates a large grid once; call it first, before
/// the command allocates. Not for commands with a real-time thread (palpate, serve): they keep
/// glibc's defaults.
void batchHeap();

/// Sets glibc's heap for a live session (palpate, serve): ARENAS arenas at most, so that the
/// memory the asynchronous regions' layouts free is reused instead of kept in per-thread arenas
/// (a new layout-builder thread takes whichever arena is free, and over an hour the resident set
/// crept up with the heap in use flat; bench/README.md, "Soak"). Call it first, before any
/// thread starts. The servo thread never allocates, so its ticks do not contend for the lock.
void liveHeap();

}  // namespace palp::tool
