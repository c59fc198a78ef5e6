#!/usr/bin/env bash
# Times `palp convert` against dcm2niix on the same DICOM series, in the same run, interleaved.
#   bench/volume/convert_vs_dcm2niix.sh [SERIES_DIR] [VOXEL_MM] [REPEATS]
# Defaults: ../shared/data/ct-ge-head-tilt, 0.5 mm, 5 repeats. Prints median wall time, CPU time
# (user + system, all threads) and peak RSS of each tool and the ratios (palp / dcm2niix; below 1
# means palp is faster / smaller), and the load average before and after (the runs are paired,
# dcm2niix then palp, so both see the same load). VOXEL_MM "auto" keeps palp's default (the
# finest input spacing).
set -euo pipefail
root="$(cd "$(dirname "$0")/../.." && pwd)"
series="${1:-$root/../shared/data/ct-ge-head-tilt}"
voxel="${2:-0.5}"
repeats="${3:-5}"
palp="${PALP:-$root/build/release/tools/palp}"
command -v dcm2niix >/dev/null || { echo "dcm2niix not installed (tools/setup.sh installs it)"; exit 1; }
[[ -x "$palp" ]] || { echo "build palp first: cmake --build --preset release --target palp"; exit 1; }
tmp="$(mktemp -d)"; trap 'rm -rf "$tmp"' EXIT

measure() {  # measure NAME CMD... -> appends "seconds kilobytes cpu-seconds" to $tmp/NAME
  local name="$1"; shift
  /usr/bin/time -f "%e %M %U %S" -o "$tmp/time" "$@" >/dev/null 2>&1
  awk '{printf "%s %s %.2f\n", $1, $2, $3 + $4}' "$tmp/time" > "$tmp/time2" && mv "$tmp/time2" "$tmp/time"
  cat "$tmp/time" >> "$tmp/$name"
}

voxelArgs=(--voxel-size "$voxel"); [[ "$voxel" == auto ]] && voxelArgs=()
load0="$(cut -d' ' -f1-3 /proc/loadavg)"
for ((i = 0; i < repeats; i++)); do
  rm -rf "$tmp/nii" && mkdir "$tmp/nii"
  measure dcm2niix dcm2niix -z n -o "$tmp/nii" "$series"
  measure palp "$palp" --quiet convert "$series" -o "$tmp/out.vdb" "${voxelArgs[@]}"
done

median() { sort -n | awk '{a[NR]=$1} END {print (NR%2) ? a[(NR+1)/2] : (a[NR/2]+a[NR/2+1])/2}'; }
pt=$(cut -d' ' -f1 "$tmp/palp" | median); pm=$(cut -d' ' -f2 "$tmp/palp" | median)
dt=$(cut -d' ' -f1 "$tmp/dcm2niix" | median); dm=$(cut -d' ' -f2 "$tmp/dcm2niix" | median)
pc=$(cut -d' ' -f3 "$tmp/palp" | median); dc=$(cut -d' ' -f3 "$tmp/dcm2niix" | median)
cpu="$(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2 | sed 's/^ *//')"
echo "machine: $(nproc) cores, $cpu; load average before $load0, after $(cut -d' ' -f1-3 /proc/loadavg)"
echo "palp runs (s): $(cut -d' ' -f1 "$tmp/palp" | tr '\n' ' ')  dcm2niix runs (s): $(cut -d' ' -f1 "$tmp/dcm2niix" | tr '\n' ' ')"
echo "series: $series ($(ls "$series" | wc -l) files), palp voxel ${voxel} mm, $repeats runs each, medians"
echo "$("$palp" info "$tmp/out.vdb" | sed -n '2,3p' | sed 's/^ */palp output: /')"
echo "nifti output: $(du -b "$tmp"/nii/*.nii | awk '{printf "%s (%d bytes) ", $2, $1}' | sed "s|$tmp/nii/||g")"
echo "vdb output: $(du -b "$tmp/out.vdb" | cut -f1) bytes"
awk -v pt="$pt" -v dt="$dt" -v pm="$pm" -v dm="$dm" -v pc="$pc" -v dc="$dc" 'BEGIN {
  printf "convert wall time: palp %.3f s; dcm2niix %.3f s; ratio %.2fx\n", pt, dt, pt / dt;
  printf "convert CPU time:  palp %.2f s; dcm2niix %.2f s; ratio %.2fx\n", pc, dc, pc / dc;
  printf "convert peak RSS:  palp %.1f MiB; dcm2niix %.1f MiB; ratio %.2fx\n", pm / 1024, dm / 1024, pm / dm }'
