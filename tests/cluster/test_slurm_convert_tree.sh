#!/usr/bin/env bash
# `palp convert-tree` as a Slurm job array (issue 37): a generated archive of 9 DICOM series
# converted by a 4-task array (`--shard $SLURM_ARRAY_TASK_ID/$SLURM_ARRAY_TASK_COUNT --resume`)
# whose task 1 fails before converting; the merge names the missing shard; the resubmitted array
# converts only task 1's series (the other tasks keep theirs); the merged result equals a
# one-process run file for file (the same .vdb names, the same bytes but for OpenVDB's per-file
# UUID, the same manifest rows). The daemons are stopped at the end whatever happens.
#
# Usage: test_slurm_convert_tree.sh PATH/TO/palp      (as root, as CI runs; ~15 s)
set -euo pipefail

PALP=$(readlink -f "${1:?usage: test_slurm_convert_tree.sh PATH/TO/palp}")
HERE=$(dirname "$(readlink -f "$0")")
# shellcheck source=one_node_slurm.sh
source "$HERE/one_node_slurm.sh"
slurm_check_tools

trap slurm_down EXIT
trap 'exit 130' INT TERM
slurm_up 2

for i in $(seq 0 8); do
  "$PALP" -q phantom avc --voxel-size 3 --noise 5 --seed "$((i + 1))" \
    --dicom-dir "$D/archive/study$((i / 3))/series$i" || fail "phantom $i"
done
"$PALP" -q convert-tree "$D/archive" "$D/one" || fail "one-process run"
[[ $(grep -c $'\tdone\t' "$D/one/manifest.tsv") -eq 9 ]] || fail "one-process run: not 9 done"

wait_records() {  # waits until jobcomp holds $1 task records (written as each task ends)
  for _ in $(seq 100); do
    [[ $(grep -c JobState= "$D/log/jobcomp.txt" 2> /dev/null || true) -ge $1 ]] && return 0
    sleep 0.1
  done
  fail "jobcomp has fewer than $1 records"
}

cat > "$D/task.sh" << EOF
#!/bin/bash
if [[ \$SLURM_ARRAY_TASK_ID == 1 && -e $D/fail_once ]]; then
  rm -f $D/fail_once
  exit 1
fi
exec "$PALP" convert-tree --resume --shard \$SLURM_ARRAY_TASK_ID/\$SLURM_ARRAY_TASK_COUNT \
  "$D/archive" "$D/array"
EOF
touch "$D/fail_once"
JOB=$(sbatch --parsable --array=0-3 -n 1 -o "$D/out/a-%A_%a.out" "$D/task.sh") || fail "sbatch"
slurm_wait_job "$JOB"
wait_records 4
[[ $(grep -c "JobState=COMPLETED" "$D/log/jobcomp.txt") -eq 3 ]] || fail "tasks 0, 2, 3 did not complete"
"$PALP" convert-tree merge "$D/array" > "$D/out/merge1.out" 2>&1 && fail "merge without shard 1 succeeded"
grep -q "shard 1/4: no manifest" "$D/out/merge1.out" || fail "merge of a gap: $(cat "$D/out/merge1.out")"

JOB2=$(sbatch --parsable --array=0-3 -n 1 -o "$D/out/b-%A_%a.out" "$D/task.sh") || fail "resubmit"
slurm_wait_job "$JOB2"
wait_records 8
[[ $(grep -c "JobState=COMPLETED" "$D/log/jobcomp.txt") -eq 7 ]] || fail "resubmitted tasks failed"
# Shard 1 holds indices 1 and 5 of 9; the other tasks had all theirs done.
grep -q "9 series found, 2 in shard 1/4: 2 converted, 0 kept" "$D/out/b-${JOB2}_1.out" ||
  fail "task 1 of the resubmission: $(cat "$D/out/b-${JOB2}_1.out")"
for t in 0 2 3; do
  grep -q " 0 converted, [0-9]* kept from an earlier run" "$D/out/b-${JOB2}_$t.out" ||
    fail "task $t of the resubmission converted again: $(cat "$D/out/b-${JOB2}_$t.out")"
done
"$PALP" convert-tree merge "$D/array" > "$D/out/merge2.out" 2>&1 || fail "merge: $(cat "$D/out/merge2.out")"

(cd "$D/one" && find . -name '*.vdb' | sort) > "$D/one.list"
(cd "$D/array" && find . -name '*.vdb' | sort) > "$D/array.list"
[[ $(wc -l < "$D/one.list") -eq 9 ]] || fail "one-process outputs: $(cat "$D/one.list")"
cmp -s "$D/one.list" "$D/array.list" || fail "the array wrote other files: $(diff "$D/one.list" "$D/array.list")"
while read -r f; do
  cmp -s -n 21 "$D/one/$f" "$D/array/$f" || fail "$f: headers differ"
  cmp -s -i 57 "$D/one/$f" "$D/array/$f" || fail "$f: contents differ"
done < "$D/one.list"
diff <(grep -v '^#' "$D/one/manifest.tsv") <(grep -v '^#' "$D/array/manifest.tsv") ||
  fail "the merged manifest's rows differ from the one-process run's"
echo "ok: sbatch --array=0-3, task 1 failed, resubmitted with --resume, merged: file for file"
echo PASS
