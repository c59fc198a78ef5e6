#pragma once
/// @file
/// The heap settings of palp's batch commands (convert, info): a grid of hundreds of MB built or
/// read leaf by leaf in one process that then exits.

namespace palp::tool {

/// Sets glibc's heap for a batch job that allocates a large grid once; call it first, before
/// the command allocates. Not for commands with a real-time thread (palpate, serve): they keep
/// glibc's defaults.
void batchHeap();

}  // namespace palp::tool
