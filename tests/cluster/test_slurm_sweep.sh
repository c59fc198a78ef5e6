#!/usr/bin/env bash
# `palp sweep` on real cluster engines (issue 33): a one-node Slurm started by hand (munged as the
# munge user on its own socket, slurmctld and slurmd with a slurm.conf in a temp dir, no
# systemd; recipe in docs/error_analysis.md), a sweep submitted as an `sbatch --array` job whose
# task 1 computes part of its range and fails, resubmitted with --resume (which computes only
# the missing samples), merged, and compared byte for byte with a one-process run; then the same
# sweep under `srun --mpi=pmix -n 2` and `mpirun --oversubscribe -np 2`, the latter resuming a
# directory with shards removed. The daemons are stopped at the end whatever happens.
#
# Usage: test_slurm_sweep.sh PATH/TO/palp      (as root, as CI runs; ~10-20 s)
set -euo pipefail

PALP=$(readlink -f "${1:?usage: test_slurm_sweep.sh PATH/TO/palp}")
HERE=$(dirname "$(readlink -f "$0")")
# shellcheck source=one_node_slurm.sh
source "$HERE/one_node_slurm.sh"
slurm_check_tools

trap slurm_down EXIT
trap 'exit 130' INT TERM
slurm_up 2

# The sweep: a 7^3 cube, 20 ms per sample, 30 samples in groups of 3.
cat > "$D/ranges.json" << 'EOF'
{"palp_sweep_ranges": 1, "mesh": {"nodes": 7, "spacing_mm": 5}, "duration_s": 0.02,
 "adaptivity_per_reference": 3, "variables": {
  "strain": {"min": 0.01, "max": 0.06}, "frequency": {"min": 10, "max": 40},
  "contact": {"min": 0, "max": 8, "integer": true},
  "youngs": {"min": 2000, "max": 20000, "scale": "log"}, "poisson": {"min": 0.3, "max": 0.45},
  "density": {"min": 900, "max": 1100}, "damping": {"min": 2, "max": 20},
  "lod": {"values": [1, 2]}, "primary": {"min": 3, "max": 12, "integer": true},
  "rate": {"min": 50, "max": 500}, "coupling": {"values": [0, 1]}}}
EOF
SWEEP=(sweep "$D/ranges.json" --samples 30 --seed 17)
"$PALP" -q "${SWEEP[@]}" -o "$D/one" || fail "one-process sweep"
[[ -s $D/one/table.csv ]] || fail "no one-process table"

wait_records() {  # waits until jobcomp holds $1 task records (written as each task ends)
  for _ in $(seq 100); do
    [[ $(grep -c JobState= "$D/log/jobcomp.txt" 2> /dev/null || true) -ge $1 ]] && return 0
    sleep 0.1
  done
  fail "jobcomp has fewer than $1 records"
}

# Job array of 3 tasks (one chunk of groups each); task 1 computes 2 samples and fails once.
cat > "$D/task.sh" << EOF
#!/bin/bash
if [[ \$SLURM_ARRAY_TASK_ID == 1 && -e $D/fail_once ]]; then
  rm -f $D/fail_once
  "$PALP" -q ${SWEEP[*]} -o $D/array --shard \$SLURM_ARRAY_TASK_ID/\$SLURM_ARRAY_TASK_COUNT \
    --resume --max-samples 2
  exit 1
fi
exec "$PALP" -q ${SWEEP[*]} -o $D/array --shard \$SLURM_ARRAY_TASK_ID/\$SLURM_ARRAY_TASK_COUNT \
  --resume
EOF
touch "$D/fail_once"
JOB=$(sbatch --parsable --array=0-2 -n 1 -o "$D/out/a-%A_%a.out" "$D/task.sh") || fail "sbatch"
slurm_wait_job "$JOB"
wait_records 3
grep -q "JobState=FAILED" "$D/log/jobcomp.txt" || fail "task 1 did not fail"
[[ $(grep -c "JobState=COMPLETED" "$D/log/jobcomp.txt") -eq 2 ]] || fail "tasks 0 and 2 did not complete"
"$PALP" -q sweep merge "$D/array" -o "$D/array/table.csv" 2> "$D/out/merge1.err" &&
  fail "merge of an incomplete sweep succeeded"
grep -q "in no shard" "$D/out/merge1.err" || fail "merge of a gap: $(cat "$D/out/merge1.err")"
[[ ! -e $D/array/table.csv ]] || fail "a table was written from an incomplete sweep"
before=$(ls "$D/array/shards" | grep -c '^shard-[0-9-]*\.csv$' | tr -d ' ')
# Resubmit: tasks 0 and 2 find their shards, task 1 computes only its 7 missing samples.
JOB2=$(sbatch --parsable --array=0-2 -n 1 -o "$D/out/b-%A_%a.out" "$D/task.sh") || fail "resubmit"
slurm_wait_job "$JOB2"
wait_records 6
[[ $(grep -c "JobState=COMPLETED" "$D/log/jobcomp.txt") -eq 5 ]] || fail "resubmitted tasks failed"
# Task 1's range is samples 9..17 in chunks of one group (3 samples, a quarter of its 3 groups
# rounded up to one); its first try wrote 9..10, so the resume writes 11, 12..14 and 15..17.
for f in 0000000011-0000000012 0000000012-0000000015 0000000015-0000000018; do
  ls "$D/array/shards" | grep -q "shard-$f.csv$" ||
    fail "the resume did not compute exactly the missing range: $(ls "$D/array/shards")"
done
after=$(ls "$D/array/shards" | grep -c '^shard-[0-9-]*\.csv$' | tr -d ' ')
[[ $after -eq $((before + 3)) ]] || fail "resume wrote $((after - before)) shards, expected 3"
"$PALP" -q sweep merge "$D/array" -o "$D/array/table.csv" || fail "merge"
cmp "$D/one/table.csv" "$D/array/table.csv" || fail "job array table differs from one process"
echo "ok: sbatch --array, one task failed, --resume, merge: byte-identical"

# MPI under Slurm: srun --mpi=pmix -n 2 (rank 0 hands out chunks and works too).
srun --mpi=pmix -n 2 -o "$D/out/srun.out" "$PALP" -q "${SWEEP[@]}" -o "$D/srun" --mpi --chunk 1 ||
  fail "srun --mpi=pmix"
cmp "$D/one/table.csv" "$D/srun/table.csv" || fail "srun table differs from one process"
echo "ok: srun --mpi=pmix -n 2: byte-identical"

# mpirun as root, resuming a directory whose shards 2 and 5 were lost.
cp -r "$D/srun" "$D/mpirun"
rm "$D/mpirun/table.csv" "$D/mpirun/shards/shard-0000000006-0000000009.csv" \
  "$D/mpirun/shards/shard-0000000015-0000000018.csv"
touch -d 2000-01-01 "$D"/mpirun/shards/*
OMPI_ALLOW_RUN_AS_ROOT=1 OMPI_ALLOW_RUN_AS_ROOT_CONFIRM=1 mpirun --oversubscribe -np 2 \
  "$PALP" -q "${SWEEP[@]}" -o "$D/mpirun" --mpi --chunk 1 --resume > "$D/out/mpirun.out" 2>&1 ||
  fail "mpirun"
fresh=$(find "$D/mpirun/shards" -name 'shard-*[0-9].csv' -newermt 2001-01-01 -printf '%f ')
[[ $fresh == *shard-0000000006-0000000009.csv* && $fresh == *shard-0000000015-0000000018.csv* &&
  $(wc -w <<< "$fresh") -eq 2 ]] || fail "mpirun --resume recomputed '$fresh', expected the 2 lost shards"
cmp "$D/one/table.csv" "$D/mpirun/table.csv" || fail "mpirun table differs from one process"
echo "ok: mpirun --oversubscribe -np 2 --resume: byte-identical"

# A shard of another sweep (another seed) is refused by name; nothing is merged.
"$PALP" -q sweep "$D/ranges.json" --samples 30 --seed 18 -o "$D/other" --shard 0/10 ||
  fail "other sweep"
cp "$D/other/shards/shard-0000000000-0000000003.csv" "$D/one/shards/shard-0000000000-0000000003.csv"
"$PALP" -q sweep merge "$D/one" -o "$D/one/again.csv" 2> "$D/out/foreign.err" &&
  fail "a foreign shard was merged"
grep -q "shard-0000000000-0000000003.csv: field 'sweep'" "$D/out/foreign.err" ||
  fail "foreign shard message: $(cat "$D/out/foreign.err")"
[[ ! -e $D/one/again.csv ]] || fail "a table was written beside a foreign shard"
# Another sweep into this directory (another seed) is refused naming the manifest's field.
"$PALP" -q sweep "$D/ranges.json" --samples 30 --seed 99 -o "$D/one" 2> "$D/out/manifest.err" &&
  fail "a sweep ran into another sweep's directory"
grep -q "manifest.json: field 'sweep'" "$D/out/manifest.err" ||
  fail "manifest message: $(cat "$D/out/manifest.err")"
echo "ok: foreign shard and another sweep's manifest refused"
echo PASS
