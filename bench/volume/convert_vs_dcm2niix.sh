#!/usr/bin/env bash
# Times `palp convert` against dcm2niix on the same DICOM series, in the same run, interleaved.
#   bench/volume/convert_vs_dcm2niix.sh [SERIES_DIR] [VOXEL_MM] [REPEATS]
# Defaults: ../shared/data/ct-ge-head-tilt, 0.5 mm, 5 repeats. Two comparisons, like with like:
# each tool's default output (palp: values uncompressed, inactive voxels dropped; dcm2niix: an
# uncompressed .nii, -z n) and each compressed (palp --compression blosc; dcm2niix -z y, gzip:
# pigz when installed, else its internal zlib). Prints median wall time, CPU time (user + system,
# all threads), peak RSS and output size of each and the ratios (palp / dcm2niix; below 1 means
# palp is faster / smaller), and the load average before and after (the runs are paired, dcm2niix
# then palp, so both see the same load). VOXEL_MM "auto" keeps palp's default (the finest input
# spacing). COMPRESSED=0 skips the compressed pair (dcm2niix's internal gzip takes ~10x its
# default's time).
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
  # Both tools write new files: replacing an existing output costs more (ext4 starts writing the
  # new file back when a rename replaces one: palp's median 0.81 s vs 0.62 s for a new name on the
  # head CT), and dcm2niix's folder is emptied before each run.
  rm -rf "$tmp/nii" "$tmp/niigz" "$tmp/out.vdb" "$tmp/blosc.vdb" && mkdir "$tmp/nii" "$tmp/niigz"
  measure dcm2niix dcm2niix -z n -o "$tmp/nii" "$series"
  measure palp "$palp" --quiet convert "$series" -o "$tmp/out.vdb" "${voxelArgs[@]}"
  [[ "${COMPRESSED:-1}" == 0 ]] && continue
  measure dcm2niix-gz dcm2niix -z y -o "$tmp/niigz" "$series"
  measure palp-blosc "$palp" --quiet convert "$series" -o "$tmp/blosc.vdb" "${voxelArgs[@]}" \
    --compression blosc
done

median() { sort -n | awk '{a[NR]=$1} END {print (NR%2) ? a[(NR+1)/2] : (a[NR/2]+a[NR/2+1])/2}'; }
col() { cut -d' ' -f"$2" "$tmp/$1" | median; }  # col NAME FIELD -> median of that field
bytes() { du -bc "$@" | tail -1 | cut -f1; }
cpu="$(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2 | sed 's/^ *//')"
echo "machine: $(nproc) cores, $cpu; load average before $load0, after $(cut -d' ' -f1-3 /proc/loadavg)"
echo "series: $series ($(ls "$series" | wc -l) files), palp voxel ${voxel} mm, $repeats runs each, medians"
echo "$("$palp" info "$tmp/out.vdb" | sed -n '2,3p' | sed 's/^ */palp output: /')"
echo "nifti output: $(du -b "$tmp"/nii/*.nii | awk '{printf "%s (%d bytes) ", $2, $1}' | sed "s|$tmp/nii/||g")"
row() {  # row LABEL PALP-NAME DCM2NIIX-NAME PALP-BYTES DCM2NIIX-BYTES
  echo "$1: palp runs (s): $(cut -d' ' -f1 "$tmp/$2" | tr '\n' ' ') dcm2niix runs (s): $(cut -d' ' -f1 "$tmp/$3" | tr '\n' ' ')"
  awk -v pt="$(col "$2" 1)" -v dt="$(col "$3" 1)" -v pm="$(col "$2" 2)" -v dm="$(col "$3" 2)" \
      -v pc="$(col "$2" 3)" -v dc="$(col "$3" 3)" -v pb="$4" -v db="$5" -v l="$1" 'BEGIN {
    printf "%s wall time: palp %.3f s; dcm2niix %.3f s; ratio %.2fx\n", l, pt, dt, pt / dt;
    printf "%s CPU time:  palp %.2f s; dcm2niix %.2f s; ratio %.2fx\n", l, pc, dc, pc / dc;
    printf "%s peak RSS:  palp %.1f MiB; dcm2niix %.1f MiB; ratio %.2fx\n", l, pm / 1024, dm / 1024, pm / dm;
    printf "%s output:    palp %.1f MB; dcm2niix %.1f MB; ratio %.2fx\n", l, pb / 1e6, db / 1e6, pb / db }'
}
row "default (palp mask, dcm2niix -z n)" palp dcm2niix "$(bytes "$tmp/out.vdb")" "$(bytes "$tmp"/nii/*.nii)"
[[ "${COMPRESSED:-1}" == 0 ]] && exit 0
row "compressed (palp blosc, dcm2niix -z y)" palp-blosc dcm2niix-gz "$(bytes "$tmp/blosc.vdb")" \
  "$(bytes "$tmp"/niigz/*.nii.gz)"
