#!/usr/bin/env bash
# ThreadSanitizer run of the tests that exercise palp's threads: the servo loop, the session's
# snapshot/command/trace paths, the C API, the TBB ray batch, the asynchronous FEM regions and
# the deformable body. Any TSan report fails the run (TSan's exit code), so "tsan-clean" is
# checked on every CI run rather than claimed. .ci/run calls it after tools/test.sh (which has
# already installed the packages).
#   bash tools/test_threads.sh            build/tsan, all the listed test executables
#   bash tools/test_threads.sh test_session   only the named ones
set -euo pipefail
cd "$(dirname "$0")/.."
if [ "$#" -gt 0 ]; then
  targets=("$@")
else
  targets=(test_base test_servo_loop test_session test_c_api test_c_api_deformable_c test_haptics test_async_regions test_async_force
           test_async_spring test_deformable_async test_deformable_head test_ray_batch test_udp_device
           test_c_api_udp_c
           test_volume_lazy_load test_volume_lazy_formats test_volume_vdb_write)
fi
cmake --preset tsan >/dev/null
cmake --build --preset tsan --target "${targets[@]}"
# halt_on_error: stop at the first report so its stacks are the last thing in the log.
export TSAN_OPTIONS="suppressions=$PWD/tools/tsan.supp halt_on_error=1 second_deadlock_stack=1"
# The ray batch (TBB workers over bundles) is its own executable, test_ray_batch, so the ray
# accuracy tests and the benchmark harness are not built here. Only the threaded cases of the
# asynchronous regions run (the synchronous accuracy cases build a global secondary each, 12
# minutes of test_async_force under TSan; the release suite runs them), the deformable regions
# session on threaded regions, its refusals and its set-up under allocation failure (its
# synchronous physics cases step both regions on the test's thread, and took most of the
# executable's 150 s under TSan; the release suite runs them) and the spring's threaded tick. The lazy loads decode slices on TBB workers (DICOM
# through GDCM, one reader per file; NIfTI, NRRD and MetaImage by pread or from the kept stored
# bytes) while the resampler fills the grid. test_volume_vdb_write: leaves packed on TBB workers (by
# convert()'s resampler and by palp::parallelForEach), written once they have joined. test_deformable_head: the shared head CT on the
# threaded regions (the servo's ticks against the secondary and layout threads).
declare -A filter=([test_deformable_async]='DeformableAsync.TicksAllocateNothing:DeformableAsync.RejectsBadOptions*:DeformableAsync.AnAllocationFailure*'
                   [test_async_spring]='AsyncSpring.Threaded*'
                   [test_async_force]='AsyncForce.StalledSecondary*:AsyncForce.TicksAllocateNothing'
                   [test_async_regions]='AsyncRegions.StalledSecondary*:AsyncRegions.Threaded*:AsyncRegions.RejectsBadInput'
                   [test_volume_vdb_write]='VdbWrite.PackedLeaves*:VdbWrite.ConvertWrites*')
failed=()
for t in "${targets[@]}"; do
  exe=$(find build/tsan/tests -type f -name "$t" -perm -u+x | head -n 1)
  if [ -z "$exe" ]; then
    echo "test_threads.sh: no executable $t under build/tsan/tests"
    failed+=("$t")
    continue
  fi
  echo "== tsan: $t"
  start=$(date +%s)
  args=(--gtest_brief=1 --gtest_filter="${filter[$t]:-*}")
  case "$t" in test_c_api | test_c_api_deformable_c | test_c_api_udp_c) args=() ;; esac  # plain C, no GoogleTest
  if "$exe" "${args[@]}"; then
    echo "== tsan: $t passed, 0 reports ($(($(date +%s) - start)) s)"
  else
    echo "== tsan: $t FAILED (exit $?: a test failed or TSan reported)"
    failed+=("$t")
  fi
done
if [ "${#failed[@]}" -gt 0 ]; then
  echo "test_threads.sh: failed under ThreadSanitizer: ${failed[*]}"
  exit 1
fi
echo "test_threads.sh: all ${#targets[@]} executables clean under ThreadSanitizer"
