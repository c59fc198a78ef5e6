#!/usr/bin/env bash
# AddressSanitizer + UndefinedBehaviorSanitizer run of the tests that take outside input: the
# volume readers and writers (NRRD, MetaImage, NIfTI, DICOM, raw data, .vdb, phantoms, meshes),
# the base layer (validation, bounds, atomic files) and the C API (its volume entry points, its
# sessions, and every number and enum field of its structs given nan, inf, 1e300, ...). The asan
# preset compiles with -fno-sanitize-recover=all, so a UBSan report aborts like an ASan one; any
# report fails the run.
# .ci/run calls it after tools/test_threads.sh (tools/test.sh has installed the packages).
#   bash tools/test_sanitize.sh                    build/asan, all the listed test executables
#   bash tools/test_sanitize.sh test_volume_formats    only the named ones
set -euo pipefail
cd "$(dirname "$0")/.."
if [ "$#" -gt 0 ]; then
  targets=("$@")
else
  targets=(test_base test_volume_formats test_volume_raw_data test_volume_reader_checks
           test_volume_checks test_volume_dicom test_volume_dicom_syntax test_volume_dicom_mosaic test_volume_dicom_enhanced test_volume_format_sniff test_volume_phantom test_volume_phantom_tumour test_volume_io
           test_volume_resample test_volume_resample_rows test_volume_lazy_load test_volume_vdb_write test_volume_cross_format test_volume_mesh test_volume_c_api test_c_api
           test_c_api_fields test_c_api_deformable test_c_api_deformable_c test_c_api_host
           test_c_api_host_c test_c_api_udp_c test_volume_from_memory test_volume_lazy_formats
           test_c_api_study)
fi
# PALP_SANITIZE_STEP=build only builds (.ci/run builds in the background while the TSan tests
# run), =run only runs an existing build; both by default.
step="${PALP_SANITIZE_STEP:-all}"
# Without the palp tool: the library and the tests are what is instrumented here (the tool's own
# checks run in tools/test.sh); the few volume tests that run `palp convert`/`palp phantom` use
# the release tool that tools/test.sh has built (PALP_BIN_DIR).
if [ "$step" != run ]; then
  cmake --preset asan -DPALP_BUILD_TOOLS=OFF >/dev/null
  # Two jobs: CI has two cores.
  cmake --build --preset asan -j 2 --target "${targets[@]}"
fi
[ "$step" = build ] && exit 0
export PALP_BIN_DIR="${PALP_BIN_DIR:-$PWD/build/release}"
if [ ! -x "$PALP_BIN_DIR/tools/palp" ]; then
  echo "test_sanitize.sh: no $PALP_BIN_DIR/tools/palp; run tools/test.sh (the release build) first"
  exit 1
fi
# halt_on_error: stop at the first report so its stacks are the last thing in the log.
# detect_leaks: a leak is a finding too.
export ASAN_OPTIONS="halt_on_error=1:abort_on_error=0:detect_leaks=1:strict_string_checks=1:detect_stack_use_after_return=1"
export UBSAN_OPTIONS="halt_on_error=1:print_stacktrace=1"
export LSAN_OPTIONS="suppressions=$PWD/tools/lsan.supp"
# Two executables at a time (CI has two cores; most of these tests use one), each into its own
# log, printed whole when it fails. The release suite (ctest -j 2) already runs them side by side.
logs="build/asan/sanitize-logs"
rm -rf "$logs"
mkdir -p "$logs"
run_one() {
  local t="$1" exe start
  exe=$(find build/asan/tests -type f -name "$t" -perm -u+x | head -n 1)
  if [ -z "$exe" ]; then
    echo "== asan: no executable $t under build/asan/tests"
    touch "$logs/$t.failed"
    return 0
  fi
  start=$(date +%s)
  local args=(--gtest_brief=1)
  case "$t" in test_c_api | test_c_api_deformable_c | test_c_api_host_c | test_c_api_udp_c) args=() ;; esac  # plain C
  if "$exe" "${args[@]}" >"$logs/$t.log" 2>&1; then
    echo "== asan: $t passed, 0 reports ($(($(date +%s) - start)) s)"
  else
    echo "== asan: $t FAILED (exit $?: a test failed or a sanitizer reported; log follows)"
    cat "$logs/$t.log"
    touch "$logs/$t.failed"
  fi
}
export -f run_one
export logs
printf '%s\n' "${targets[@]}" | xargs -P 2 -I{} bash -c 'run_one "$1"' _ {}
failed=()
for t in "${targets[@]}"; do
  [ -e "$logs/$t.failed" ] && failed+=("$t")
done
if [ "${#failed[@]}" -gt 0 ]; then
  echo "test_sanitize.sh: failed under AddressSanitizer+UBSan: ${failed[*]}"
  exit 1
fi
echo "test_sanitize.sh: all ${#targets[@]} executables clean under AddressSanitizer+UBSan"
