#!/usr/bin/env bash
# Times `palp convert-tree` on a generated archive of small DICOM series against one `palp convert`
# process per series and one dcm2niix run per series, interleaved, and checks that a Slurm job
# array of 4 tasks (`--shard i/4`, then `palp convert-tree merge`) gives the one-process result
# file for file.
#   bench/volume/convert_tree_bench.sh [SERIES] [REPEATS] [VOXEL_MM]
# Defaults: 100 series, 3 repeats, 2 mm. Each series is `palp phantom avc` at VOXEL_MM with its
# own noise seed (fresh UIDs): about 50 slices of 60 x 60 at 2 mm. Prints each run and the median
# wall time, CPU time (user + system) and ratios. The Slurm part needs root and tools/setup.sh's
# slurm-wlm and munge (tests/cluster/one_node_slurm.sh starts a one-node cluster); SLURM=0 skips it.
set -euo pipefail
root="$(cd "$(dirname "$0")/../.." && pwd)"
count="${1:-100}"
repeats="${2:-3}"
voxel="${3:-2}"
palp="${PALP:-$root/build/release/tools/palp}"
command -v dcm2niix > /dev/null || { echo "dcm2niix not installed (tools/setup.sh installs it)"; exit 1; }
[[ -x "$palp" ]] || { echo "build palp first: cmake --build --preset release --target palp"; exit 1; }
palp="$(readlink -f "$palp")"
work="$(mktemp -d /tmp/palp-tree-bench.XXXXXX)"
cleanup() { rm -rf "$work"; }
trap cleanup EXIT

echo "generating $count series under $work/archive ..."
for ((i = 0; i < count; i++)); do
  d="$work/archive/study$((i / 10))/series$i"
  "$palp" -q phantom avc --voxel-size "$voxel" --noise 5 --seed "$((i + 1))" --dicom-dir "$d"
done
files=$(find "$work/archive" -type f | wc -l)
bytes=$(du -sb "$work/archive" | cut -f1)
find "$work/archive" -mindepth 2 -maxdepth 2 -type d | sort > "$work/series.list"

measure() {  # measure NAME CMD... -> appends "wall cpu" to $work/times.NAME
  local name="$1"
  shift
  /usr/bin/time -f "%e %U %S" -o "$work/time" "$@" > /dev/null 2>&1 || true
  awk '{printf "%s %.2f\n", $1, $2 + $3}' "$work/time" >> "$work/times.$name"
}
perSeriesPalp() {  # one process per series, as a script converting an archive runs it today
  local i=0
  while read -r s; do
    "$palp" -q convert "$s" -o "$work/each/$i.vdb"
    i=$((i + 1))
  done < "$work/series.list"
}
perSeriesDcm2niix() {
  local i=0
  while read -r s; do
    mkdir -p "$work/nii/$i"
    dcm2niix -z n -o "$work/nii/$i" "$s" > /dev/null
    i=$((i + 1))
  done < "$work/series.list"
}
export -f perSeriesPalp perSeriesDcm2niix
export palp work
load0="$(cut -d' ' -f1-3 /proc/loadavg)"
for ((r = 0; r < repeats; r++)); do
  rm -rf "$work/tree" "$work/each" "$work/nii" && mkdir -p "$work/each" "$work/nii"
  measure tree "$palp" -q convert-tree "$work/archive" "$work/tree"
  measure each bash -c perSeriesPalp
  measure dcm2niix bash -c perSeriesDcm2niix
done
done_rows=$(grep -c $'\tdone\t' "$work/tree/manifest.tsv" || true)
[[ $done_rows -eq $count ]] || { echo "FAIL: $done_rows of $count series done"; exit 1; }

median() { sort -n | awk '{a[NR]=$1} END {print (NR%2) ? a[(NR+1)/2] : (a[NR/2]+a[NR/2+1])/2}'; }
col() { cut -d' ' -f"$2" "$work/times.$1" | median; }
cpu="$(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2 | sed 's/^ *//')"
echo "machine: $(nproc) cores, $cpu; load average before $load0, after $(cut -d' ' -f1-3 /proc/loadavg)"
echo "archive: $count series, $files files, $((bytes / 1000)) kB; palp voxel $voxel mm (the phantom's spacing); $repeats interleaved runs"
for n in tree each dcm2niix; do echo "$n runs (wall s CPU s): $(paste -sd ';' "$work/times.$n")"; done
awk -v t="$(col tree 1)" -v e="$(col each 1)" -v d="$(col dcm2niix 1)" \
    -v tc="$(col tree 2)" -v ec="$(col each 2)" -v dc="$(col dcm2niix 2)" -v n="$count" 'BEGIN {
  printf "median wall: convert-tree %.2f s (%.1f ms a series); %d x palp convert %.2f s; %d x dcm2niix %.2f s\n", t, 1000 * t / n, n, e, n, d;
  printf "median CPU:  convert-tree %.2f s; palp convert %.2f s; dcm2niix %.2f s\n", tc, ec, dc;
  printf "convert-tree vs palp convert: %.2fx faster; vs dcm2niix: %.2fx (below 1: faster)\n", e / t, t / d }'

# The same archive as a Slurm job array of 4 tasks, merged, against the one-process run.
[[ "${SLURM:-1}" == 0 ]] && exit 0
if [[ $(id -u) -ne 0 || ! -x /usr/sbin/slurmctld || ! -x /usr/sbin/munged ]]; then
  echo "slurm: skipped (needs root and slurm-wlm + munge: tools/setup.sh)"
  exit 0
fi
# shellcheck source=../../tests/cluster/one_node_slurm.sh
source "$root/tests/cluster/one_node_slurm.sh"
trap 'slurm_down; cleanup' EXIT
slurm_up 2
cat > "$D/task.sh" << EOF
#!/bin/bash
exec "$palp" -q convert-tree --resume --shard \$SLURM_ARRAY_TASK_ID/\$SLURM_ARRAY_TASK_COUNT \
  "$work/archive" "$work/array"
EOF
t0=$(date +%s.%N)
JOB=$(sbatch --parsable --array=0-3 -n 1 -o "$D/out/t-%A_%a.out" "$D/task.sh") || fail "sbatch"
slurm_wait_job "$JOB" 600
t1=$(date +%s.%N)
for _ in $(seq 100); do
  [[ $(grep -c JobState= "$D/log/jobcomp.txt" 2> /dev/null || true) -ge 4 ]] && break
  sleep 0.1
done
[[ $(grep -c "JobState=COMPLETED" "$D/log/jobcomp.txt") -eq 4 ]] || fail "not every task completed"
"$palp" convert-tree merge "$work/array" || fail "merge"
# File for file: the same names; each .vdb the same bytes but for OpenVDB's per-file UUID (36
# bytes at offset 21 of the header), the manifests' rows identical.
(cd "$work/tree" && find . -name '*.vdb' | sort) > "$work/one.list"
(cd "$work/array" && find . -name '*.vdb' | sort) > "$work/array.list"
cmp -s "$work/one.list" "$work/array.list" || fail "the array wrote other files than the one process"
while read -r f; do
  cmp -s -n 21 "$work/tree/$f" "$work/array/$f" || fail "$f: headers differ"
  cmp -s -i 57 "$work/tree/$f" "$work/array/$f" || fail "$f: contents differ"
done < "$work/one.list"
diff <(grep -v '^#' "$work/tree/manifest.tsv") <(grep -v '^#' "$work/array/manifest.tsv") > /dev/null ||
  fail "the merged manifest's rows differ from the one-process manifest's"
echo "slurm: a 4-task array (--shard i/4, 2 CPUs) took $(awk -v a="$t0" -v b="$t1" 'BEGIN {printf "%.1f", b - a}') s, merged: $(wc -l < "$work/one.list") outputs and every manifest row equal to the one-process run's"
