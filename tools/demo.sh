#!/usr/bin/env bash
# Set-up + build + the main job on a built-in default: the thesis's AVC phantom (a rigid plate
# 10 mm deep hiding a small rigid box 20 mm deep in quadrant 2) is written as a DICOM series,
# converted with `palp convert`, and palpated with `palp palpate`: a simulated hand rasters the
# surface with AVC (accumulate rays) and the stiffness felt is mapped to out/demo/avc-map.png,
# in which the hidden box shows; out/demo/avc-map-first-hit.png is the same raster with
# first-hit rays, which stop on the plate, so the box stays hidden. Outputs go to out/demo/
# (override with PALP_DEMO_DIR).
set -euo pipefail
cd "$(dirname "$0")/.."
bash tools/setup.sh
unity=()  # a fresh build directory compiles the modules as unity batches, as tools/test.sh does
[ -f build/release/CMakeCache.txt ] || unity=(-DPALP_UNITY_BUILD=ON)
cmake --preset release "${unity[@]}"
cmake --build --preset release --target palp
palp=build/release/tools/palp
out="${PALP_DEMO_DIR:-out/demo}"
rm -rf "$out/dicom" && mkdir -p "$out"
"$palp" phantom avc --quadrant 2 --noise 10 --seed 7 --dicom-dir "$out/dicom"
"$palp" info "$out/dicom"
"$palp" convert "$out/dicom" -o "$out/avc.vdb" --voxel-size 0.5
"$palp" info "$out/avc.vdb"
# Raster over the surface (x, z in +-45 mm, 1 mm lines, 100 mm/s, pressed 4 mm along +y),
# 2 mm map pixels binned where the centre ray ends; image right = +x (patient left), up = +z
# (superior): the surface seen from the anterior side.
raster=(--trajectory raster --spacing 1 --speed 100 --depth 4 --map-pixel 2 --map-at ray-end)
"$palp" palpate "$out/avc.vdb" --mode avc --source accumulate "${raster[@]}" \
  --map "$out/avc-map.png" --trace "$out/avc-trace.csv"
"$palp" palpate "$out/avc.vdb" --mode avc --source first-hit --threshold 500 "${raster[@]}" \
  --map "$out/avc-map-first-hit.png"
echo "demo: see $out/avc-map.png; the phantom hid the box in quadrant 2 (upper left: x < 0, z > 0)"
