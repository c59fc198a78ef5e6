#!/usr/bin/env bash
# Runs `palp study STUDY.json` for participants 0..N-1 (simulated observers), each into its own
# log under OUT, then pools every log per condition: the mean of the participants' reversal
# JNDs (with their sd) and one psychometric fit of all trials (bench/README.md, "Perception
# studies"). Usage: run_participants.sh STUDY.json N OUT [palp binary]
set -euo pipefail
study=$1 n=$2 out=$3
palp=${4:-build/release/tools/palp}
mkdir -p "$out"
start=$(date +%s.%N)
for ((p = 0; p < n; p++)); do
  "$palp" -q study "$study" --log "$out/p$p.csv" --participant "$p" --json > "$out/p$p.json"
done
end=$(date +%s.%N)
/usr/bin/python3 - "$out" "$n" "$start" "$end" <<'PY'
import json, statistics, sys
out, n, t0, t1 = sys.argv[1], int(sys.argv[2]), float(sys.argv[3]), float(sys.argv[4])
runs = [json.load(open(f"{out}/p{p}.json")) for p in range(n)]
names = [c["name"] for c in runs[0]["conditions"]]
print(f"{runs[0]['study']}: {n} participants, {sum(r['trials'] for r in runs)} trials, {t1 - t0:.1f} s")
for i, name in enumerate(names):
    rev = [r["conditions"][i]["jnd_procedure_percent"] for r in runs]
    fit = [r["conditions"][i]["jnd_fit_percent"] for r in runs]
    rev = [v for v in rev if v is not None]
    fit = [v for v in fit if v is not None]
    print(f"  {name:8s} reversals {statistics.mean(rev):6.2f} +- {statistics.stdev(rev):5.2f} %"
          f"   per-participant fit {statistics.median(fit):6.2f} % (median)")
PY
