#!/usr/bin/env bash
# The long soak (bench/README.md, "Soak"): bench_soak's three scenes (rigid, deformable, UDP
# bridge) for SECONDS each in one-minute windows, every check on, the servo at SCHED_FIFO on the
# last CPU, while another process keeps CPU 0 busy (a shell loop at normal priority).
#   bash bench/haptics/soak/soak.sh [SECONDS per scene, default 3600] [OUT.json] [bench_soak args...]
set -euo pipefail
cd "$(dirname "$0")/../../.."
seconds="${1:-3600}"
out="${2:-soak.json}"
shift $(($# > 2 ? 2 : $#))
exe=build/release/bench/haptics/bench_soak
# One glibc arena, as palp palpate and palp serve set for themselves (tools/palp/batch_heap.h,
# liveHeap): with glibc's default the regions' resident set creeps up as layouts come and go.
export MALLOC_ARENA_MAX="${MALLOC_ARENA_MAX:-1}"
[ -x "$exe" ] || cmake --build --preset release --target bench_soak
taskset -c 0 bash -c 'while :; do :; done' &
load=$!
trap 'kill "$load" 2>/dev/null || true' EXIT
"$exe" --seconds "$seconds" --window 60 --check --json "$out" "$@"
