#!/bin/bash
# Issue 34: the displaced-bone raster (the command) for bone positions -1, 0 and +1.
# usage: bone.sh OUTDIR MODE SEED   (then cue.py and tilt.py on OUTDIR/bone_MODE_D*_sSEED.csv)
out=$1; mode=$2; seed=$3; mkdir -p "$out"
P=$(dirname "$0")/../../build/release/tools/palp
for D in -1 0 1; do
  "$P" palpate --phantom bone --displacement $D --noise 10 --seed $seed \
    --deformable --mode $mode --trajectory raster --spacing 4 --speed 100 --depth 3 \
    --trace "$out/bone_${mode}_D${D}_s$seed.csv" > "$out/bone_${mode}_D${D}_s$seed.log" 2>&1
done
