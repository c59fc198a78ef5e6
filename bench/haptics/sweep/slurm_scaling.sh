#!/usr/bin/env bash
# Scaling of `palp sweep` from one to two processes under a real Slurm (issue 33's goal: >= 1.8x
# on this 2-core machine). Starts the one-node Slurm of tests/cluster, then, for each of R
# paired rounds, runs the same sweep as one task (`sbatch -n 1`) and as a 2-task job array
# (`--shard $SLURM_ARRAY_TASK_ID/2`), each into a fresh directory, timing submission to the end
# of the last task; checks the merged array table equals the one-task table byte for byte; prints
# each round, the medians, the ratio and samples per second per core. Needs root; run it on an
# otherwise idle machine (a build beside it measures the build).
#
# Usage: slurm_scaling.sh PATH/TO/palp [RANGES.json] [SAMPLES] [ROUNDS]
set -euo pipefail

PALP=$(readlink -f "${1:?usage: slurm_scaling.sh PATH/TO/palp [RANGES] [SAMPLES] [ROUNDS]}")
ROOT=$(dirname "$(readlink -f "$0")")/../../..
RANGES=$(readlink -f "${2:-$ROOT/bench/haptics/sweep/cube13.json}")
N=${3:-256}
ROUNDS=${4:-3}
# shellcheck source=../../../tests/cluster/one_node_slurm.sh
source "$ROOT/tests/cluster/one_node_slurm.sh"
slurm_check_tools
trap slurm_down EXIT
trap 'exit 130' INT TERM
slurm_up 2

SWEEP="sweep $RANGES --samples $N --seed 7"
cat > "$D/one.sh" << EOF
#!/bin/bash
exec "$PALP" -q $SWEEP -o "\$1"
EOF
cat > "$D/array.sh" << EOF
#!/bin/bash
exec "$PALP" -q $SWEEP -o "\$1" --shard \$SLURM_ARRAY_TASK_ID/\$SLURM_ARRAY_TASK_COUNT
EOF
chmod +x "$D/one.sh" "$D/array.sh"

run() {  # NAME SBATCH-ARGS... : prints the wall seconds from submission to the job's end
  local dir=$D/$1
  shift
  local t0 job
  t0=$(date +%s.%N)
  job=$(sbatch --parsable -o "$D/out/%x-%A_%a.out" "$@" "$dir") || fail "sbatch $*"
  slurm_wait_job "$job" 7200
  echo "$(date +%s.%N) - $t0" | bc
}

one=() two=()
for r in $(seq "$ROUNDS"); do
  t1=$(run "one$r" -n 1 -c 1 "$D/one.sh")
  t2=$(run "two$r" --array=0-1 -n 1 -c 1 "$D/array.sh")
  "$PALP" -q sweep merge "$D/two$r" -o "$D/two$r/table.csv" || fail "merge round $r"
  cmp "$D/one$r/table.csv" "$D/two$r/table.csv" || fail "round $r: array table differs"
  one+=("$t1") two+=("$t2")
  printf 'round %d: 1 task %.1f s, 2 tasks %.1f s, ratio %.2f\n' "$r" "$t1" "$t2" \
    "$(echo "$t1 / $t2" | bc -l)"
done
median() { printf '%s\n' "$@" | sort -g | awk '{a[NR]=$1} END {print (NR % 2) ? a[(NR + 1) / 2] : (a[NR / 2] + a[NR / 2 + 1]) / 2}'; }
m1=$(median "${one[@]}") m2=$(median "${two[@]}")
printf 'median of %d rounds, %d samples (%s): 1 task %.1f s (%.2f samples/s/core), ' \
  "$ROUNDS" "$N" "$(basename "$RANGES")" "$m1" "$(echo "$N / $m1" | bc -l)"
printf '2 tasks %.1f s (%.2f samples/s/core), speed-up %.2fx\n' "$m2" \
  "$(echo "$N / $m2 / 2" | bc -l)" "$(echo "$m1 / $m2" | bc -l)"
