#!/usr/bin/env bash
# The installed package, checked from outside the tree: installs an existing build (no rebuild)
# into a temporary prefix, checks the libraries' SONAMEs and RUNPATHs and the installed palp
# tool, then builds and runs the consumers in tests/package against the prefix: both with
# find_package(palp CONFIG) (CMAKE_PREFIX_PATH), the C one also with pkg-config
# (PKG_CONFIG_PATH); with the Python module, imports it and runs the installed viewer
# (bin/palp-viewer) off screen. Any failure fails the script. .ci/run calls it after tools/test.sh.
#   bash tools/test_package.sh              the release build (build/release)
#   PALP_BUILD_DIR=build/debug bash tools/test_package.sh
#   PALP_KEEP_PREFIX=1 ...                  keep the temporary prefix (its path is printed)
set -euo pipefail
cd "$(dirname "$0")/.."
build="${PALP_BUILD_DIR:-build/release}"
fail() { echo "test_package: FAILED: $*" >&2; exit 1; }
# The file the loader picks for libpalp_haptics when running $1 (resolved).
loaded_haptics() { env -u LD_LIBRARY_PATH ldd "$1" | awk '/libpalp_haptics/ {print $3}' | xargs -r realpath; }
[[ -f "$build/CMakeCache.txt" ]] || fail "no build in '$build' (run tools/test.sh first)"
for tool in readelf pkg-config cc; do
  command -v "$tool" >/dev/null || fail "'$tool' not installed"
done

tmp="$(mktemp -d /tmp/palp-package.XXXXXX)"
if [[ -z "${PALP_KEEP_PREFIX:-}" ]]; then trap 'rm -rf "$tmp"' EXIT; fi
prefix="$tmp/prefix"
echo "test_package: installing $build into $prefix"
cmake --install "$build" --prefix "$prefix" >"$tmp/install.log" ||
  { cat "$tmp/install.log" >&2; fail "cmake --install $build"; }

version="$(sed -n 's/^CMAKE_PROJECT_VERSION:STATIC=//p' "$build/CMakeCache.txt")"
[[ -n "$version" ]] || fail "no CMAKE_PROJECT_VERSION in $build/CMakeCache.txt"
major="${version%%.*}"
minor="${version#*.}"; minor="${minor%%.*}"
if ((major > 0)); then soversion="$major"; else soversion="$major.$minor"; fi
libdir="$(dirname "$(find "$prefix" -name palp.pc -path '*/pkgconfig/*' | head -n1)")/.."
libdir="$(cd "$libdir" && pwd)"

# Every module: a versioned file, its SONAME, the development symlink, RUNPATH $ORIGIN.
for m in base kernels volume_core volume fem tissue rendering devices haptics studies capi perception; do
  lib="$libdir/libpalp_$m.so.$version"
  [[ -f "$lib" && ! -L "$lib" ]] || fail "$lib missing"
  [[ "$(readlink "$libdir/libpalp_$m.so")" == "libpalp_$m.so.$soversion" ]] ||
    fail "libpalp_$m.so does not point at libpalp_$m.so.$soversion"
  dyn="$(readelf -d "$lib")"
  grep -q "SONAME.*\[libpalp_$m.so.$soversion\]" <<<"$dyn" || fail "$lib: SONAME is not libpalp_$m.so.$soversion"
  grep -q 'RUNPATH.*\[\$ORIGIN\]' <<<"$dyn" || fail "$lib: RUNPATH is not \$ORIGIN"
  ! grep -q "$PWD" <<<"$dyn" || fail "$lib refers to the build tree"
  echo "  libpalp_$m.so.$version: SONAME libpalp_$m.so.$soversion, RUNPATH \$ORIGIN"
done
for h in palp/palp.h palp/haptics/session.h palp/haptics/devices/device.h \
  palp/haptics/rendering/coupling.h palp/haptics/tissue/deformable.h palp/studies/scalar_map.h \
  palp/volume/volume.h palp/fem/fem_model.h palp/kernels/volume_ray.h palp/base/error.h \
  palp/perception/quest.h palp/palp_study.h palp/studies/study_session.h; do
  [[ -f "$prefix/include/$h" ]] || fail "header $h not installed"
done

# The servo's libraries (the runtime and every room below it) load nothing that draws: libpng
# and cairo are palp::studies' alone.
for m in tissue rendering devices haptics; do
  drawing="$(env -u LD_LIBRARY_PATH ldd "$libdir/libpalp_$m.so.$version" | grep -E 'libpng|libcairo' || true)"
  [[ -z "$drawing" ]] || fail "libpalp_$m loads a drawing library: $drawing"
done
# (ldd's output first, then grep: with pipefail, `ldd | grep -q` fails whenever grep's early exit
# makes ldd die of SIGPIPE, as it did on a loaded machine.)
studies_libs="$(env -u LD_LIBRARY_PATH ldd "$libdir/libpalp_studies.so.$version")"
grep -q libcairo <<<"$studies_libs" ||
  fail "libpalp_studies does not load libcairo (the check above would prove nothing)"
echo "  libpalp_{tissue,rendering,devices,haptics}: no libpng, no libcairo (libpalp_studies has them)"

# The tool runs from the prefix alone (its RUNPATH, not the build tree's).
dyn="$(readelf -d "$prefix/bin/palp")"
grep -q 'RUNPATH.*\[\$ORIGIN/\.\./lib' <<<"$dyn" || fail "bin/palp: RUNPATH is not \$ORIGIN/../lib"
! grep -q "$PWD" <<<"$dyn" || fail "bin/palp refers to the build tree"
got="$(env -u LD_LIBRARY_PATH "$prefix/bin/palp" --version)" || fail "bin/palp --version"
[[ "$got" == "palp $version" ]] || fail "bin/palp --version printed '$got', expected 'palp $version'"
unresolved="$(env -u LD_LIBRARY_PATH ldd "$prefix/bin/palp" | grep 'not found' || true)"
[[ -z "$unresolved" ]] || fail "bin/palp: $unresolved"
# The executable links palp_volume_core alone; its other commands are a module beside
# libpalp_tool.so (tools/CMakeLists.txt), which loads the installed libpalp_haptics.
[[ -z "$(loaded_haptics "$prefix/bin/palp")" ]] ||
  fail "bin/palp loads libpalp_haptics at start-up (convert and --version should not)"
commands="$libdir/libpalp_tool_commands.so"
[[ -f "$commands" ]] || fail "$commands missing"
! grep -q "$PWD" <<<"$(readelf -d "$commands" "$libdir/libpalp_tool.so.$version")" ||
  fail "the tool's libraries refer to the build tree"
haptics="$libdir/libpalp_haptics.so.$version"
[[ "$(loaded_haptics "$commands")" == "$haptics" ]] ||
  fail "$commands does not load the installed libpalp_haptics"
echo "  bin/palp --version: $got (RUNPATH \$ORIGIN/../lib; libpalp_haptics not loaded)"
# A command of the module runs from the prefix alone, through the installed module.
env -u LD_LIBRARY_PATH LD_DEBUG=files "$prefix/bin/palp" --quiet palpate --phantom avc --fast \
  --seconds 0.2 --trace "$tmp/palpate.csv" >"$tmp/palpate.log" 2>&1 ||
  { cat "$tmp/palpate.log" >&2; fail "bin/palp palpate from the prefix"; }
grep -q "file=$prefix/.*/libpalp_tool_commands.so .*dynamically loaded" "$tmp/palpate.log" ||
  fail "bin/palp palpate did not open $commands"
echo "  bin/palp palpate: through $(basename "$commands") from the prefix"
# DICOM through the installed plugin (libpalp_volume_dicom.so, opened beside
# libpalp_volume_core at the first DICOM): a generated series converts from the prefix alone,
# without loading OpenVDB's library; a Blosc-compressed output opens the installed
# libpalp_volume (and so OpenVDB) for load() and save().
plugin="$libdir/libpalp_volume_dicom.so"
[[ -f "$plugin" ]] || fail "$plugin missing"
! grep -q "$PWD" <<<"$(readelf -d "$plugin")" || fail "$plugin refers to the build tree"
env -u LD_LIBRARY_PATH "$prefix/bin/palp" --quiet phantom avc --dicom-dir "$tmp/series" \
  >"$tmp/phantom.log" 2>&1 || { cat "$tmp/phantom.log" >&2; fail "bin/palp phantom --dicom"; }
env -u LD_LIBRARY_PATH LD_DEBUG=files "$prefix/bin/palp" --quiet convert "$tmp/series" \
  -o "$tmp/series.vdb" >"$tmp/convert.log" 2>&1 || { cat "$tmp/convert.log" >&2; fail "bin/palp convert of a DICOM series"; }
grep -q "file=$prefix/.*/libpalp_volume_dicom.so .*dynamically loaded" "$tmp/convert.log" || fail "bin/palp convert did not open $plugin"
! grep -q "file=.*libopenvdb" "$tmp/convert.log" || fail "bin/palp convert of a DICOM series loaded libopenvdb"
env -u LD_LIBRARY_PATH LD_DEBUG=files "$prefix/bin/palp" --quiet convert "$tmp/series" \
  -o "$tmp/series_blosc.vdb" --compression blosc >"$tmp/convert_blosc.log" 2>&1 ||
  { cat "$tmp/convert_blosc.log" >&2; fail "bin/palp convert --compression blosc"; }
grep -q "file=$prefix/.*/libpalp_volume.so.$soversion .*dynamically loaded" "$tmp/convert_blosc.log" ||
  fail "bin/palp convert --compression blosc did not open the installed libpalp_volume"
echo "  bin/palp convert: a DICOM series through $(basename "$plugin") from the prefix, no libopenvdb"
echo "  bin/palp convert --compression blosc: through the installed libpalp_volume"

# The consumers with CMake.
cmake -S tests/package -B "$tmp/consumer" -G Ninja -DCMAKE_BUILD_TYPE=Release \
  -DCMAKE_PREFIX_PATH="$prefix" >"$tmp/configure.log" 2>&1 ||
  { cat "$tmp/configure.log" >&2; fail "configuring tests/package with find_package(palp CONFIG)"; }
cmake --build "$tmp/consumer" >"$tmp/build.log" 2>&1 ||
  { cat "$tmp/build.log" >&2; fail "building tests/package"; }
consumer_libs="$(env -u LD_LIBRARY_PATH ldd "$tmp/consumer/consumer_c")"
grep -q "libpalp_capi.so.$soversion" <<<"$consumer_libs" ||
  fail "consumer_c does not load libpalp_capi"
for exe in consumer_c consumer_cpp; do
  [[ "$(loaded_haptics "$tmp/consumer/$exe")" == "$haptics" ]] ||
    fail "$exe does not load the installed libpalp_haptics"
  env -u LD_LIBRARY_PATH "$tmp/consumer/$exe" || fail "$exe (CMake)"
done

# The C consumer with pkg-config alone.
export PKG_CONFIG_PATH="$libdir/pkgconfig"
[[ "$(pkg-config --modversion palp)" == "$version" ]] || fail "pkg-config --modversion palp"
cflags="$(pkg-config --cflags palp)"
libs="$(pkg-config --libs palp)"
echo "  pkg-config: --cflags '$cflags' --libs '$libs'"
# shellcheck disable=SC2086  # word splitting of the flags is intended
cc -std=c11 -Wall -Wextra -Werror $cflags tests/package/consumer.c -o "$tmp/consumer_c_pc" \
  $libs -Wl,-rpath,"$(pkg-config --variable=libdir palp)" -lm || fail "cc with pkg-config"
env -u LD_LIBRARY_PATH "$tmp/consumer_c_pc" || fail "consumer_c (pkg-config)"

# The Python module, when the build has it (PALP_BUILD_PYTHON): imported from the prefix by
# Debian's python3 with a clean environment, it loads the installed libraries (RUNPATH) and
# makes a phantom.
pydir="$prefix/lib/python3/dist-packages"
if [[ -d "$pydir/palp" ]]; then
  (cd "$tmp" && env -u LD_LIBRARY_PATH PYTHONPATH="$pydir" /usr/bin/python3 -c '
import sys, palp
assert palp.__file__.startswith(sys.argv[1]), palp.__file__
libs = {l.split()[-1] for l in open("/proc/self/maps") if "libpalp_haptics" in l}
assert libs == {sys.argv[2]}, libs
assert palp.phantom("avc", voxel_size=2e-3).active_voxel_count == 62500
' "$pydir" "$haptics") || fail "python3: import palp from $pydir"
  echo "  python3: palp imported from $pydir, loading $haptics"

  # The viewer as an installed user runs it: bin/palp-viewer from the prefix with a clean
  # environment (no PYTHONPATH, no DISPLAY: it finds the installed module itself), off screen
  # under xvfb-run for two frames of a phantom's live session.
  viewer="$prefix/bin/palp-viewer"
  [[ -x "$viewer" ]] || fail "bin/palp-viewer not installed as an executable"
  command -v xvfb-run >/dev/null || fail "'xvfb-run' not installed (Debian: xvfb)"
  (cd "$tmp" && env -u LD_LIBRARY_PATH -u PYTHONPATH /usr/bin/python3 -c 'import palp') \
    2>/dev/null && fail "python3 imports palp without the prefix (the check below proves nothing)"
  (cd "$tmp" && env -u LD_LIBRARY_PATH -u PYTHONPATH -u DISPLAY xvfb-run -a "$viewer" \
    --phantom avc --offscreen "$tmp/viewer" --frames 2 --fps 10 --size 320x240) \
    >"$tmp/viewer.log" 2>&1 || { cat "$tmp/viewer.log" >&2; fail "bin/palp-viewer --offscreen"; }
  /usr/bin/python3 - "$tmp/viewer" <<'PY' || fail "bin/palp-viewer: frames.json or its PNGs"
import json, os, sys
frames = json.load(open(os.path.join(sys.argv[1], "frames.json")))["frames"]
assert len(frames) == 2, frames
assert frames[1]["tick"] > frames[0]["tick"] > 0, frames
for f in frames:
    png = open(os.path.join(sys.argv[1], f["png"]), "rb").read()
    assert png[:8] == b"\x89PNG\r\n\x1a\n" and len(png) > 1000, f["png"]
PY
  echo "  bin/palp-viewer: $(tail -n1 "$tmp/viewer.log")"
fi
echo "test_package: ok (prefix $prefix)"
