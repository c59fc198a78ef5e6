#!/usr/bin/env bash
# Set-up + build + the main job on a built-in default: the thesis's AVC phantom is generated,
# written as a DICOM series, converted with `palp convert` and described with `palp info`.
# Outputs go to out/demo/ (override with PALP_DEMO_DIR).
set -euo pipefail
cd "$(dirname "$0")/.."
bash tools/setup.sh
cmake --preset release
cmake --build --preset release --target palp
palp=build/release/tools/palp
out="${PALP_DEMO_DIR:-out/demo}"
rm -rf "$out/dicom" && mkdir -p "$out"
"$palp" phantom avc --quadrant 2 --noise 10 --seed 7 --dicom-dir "$out/dicom"
"$palp" info "$out/dicom"
"$palp" convert "$out/dicom" -o "$out/avc.vdb" --voxel-size 0.5
"$palp" info "$out/avc.vdb"
