#!/bin/bash
# Issue 34: held presses on the bone phantom, 3, 6 and 9 mm deep, AVC and AVCEC, on rigid
# tissue and on deformable tissue with both solvers; the buzz criteria by holdstat.py.
# usage: holds.sh OUTDIR
out=$1; mkdir -p "$out"
P=$(dirname "$0")/../../build/release/tools/palp
for mode in avc avcec; do for d in 3 6 9; do
  run() { "$P" palpate --phantom bone --trajectory press --depth $d --hold 2 --fast --seconds 1.2 \
            --mode $mode "$@" > /dev/null 2>&1; }
  run --trace "$out/${mode}_rigid_d$d.csv"
  for s in explicit regions; do run --deformable --fem-solver $s --trace "$out/${mode}_${s}_d$d.csv"; done
done; done
for f in "$out"/*.csv; do "${PYTHON:-/usr/bin/python3}" "$(dirname "$0")/holdstat.py" "$f"; done
