#pragma once
/// @file
/// The heap settings of palp's commands: the batch ones (convert, info: a grid of hundreds of MB
/// built or read leaf by leaf in one process that then exits) and the live ones (palpate, serve).

namespace palp::tool {

/// Sets glibc's heap for a batch job that allocates a large grid once; call it first, before
/// the command allocates. Not for commands with a real-time thread (palpate, serve: liveHeap).
void batchHeap();

/// Sets glibc's heap for a live session (palpate, serve): one arena, so that the memory the
/// asynchronous regions' layouts free (built on the builder thread, completed and freed on the
/// secondary thread) is reused rather than kept across per-thread arenas: with glibc's default
/// the resident set crept up over an hour while the heap in use stayed flat (bench/README.md,
/// "Soak"). Call it first, before any thread starts. The servo thread never allocates, so its
/// ticks never wait for the arena's lock.
void liveHeap();

}  // namespace palp::tool
