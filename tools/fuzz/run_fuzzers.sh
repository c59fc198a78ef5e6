#!/usr/bin/env bash
# Configures and builds the 'fuzz' preset (clang, libFuzzer + ASan + UBSan) and runs every palp
# fuzz target for a bounded time, one after the other.
#
#   tools/fuzz/run_fuzzers.sh [SECONDS_PER_TARGET]    (default 60)
#
# Environment: PALP_FUZZ_BUILD_DIR (default build/fuzz), PALP_FUZZ_JOBS (default 2).
# The checked-in seeds (tools/fuzz/corpus/<target>) are only read; new inputs go to
# <build>/corpus/<target>, crashes to <build>/artifacts/<target>. Exits non-zero when a target
# found something.
set -euo pipefail

seconds="${1:-60}"
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)"
build="${PALP_FUZZ_BUILD_DIR:-$root/build/fuzz}"
jobs="${PALP_FUZZ_JOBS:-2}"
targets=(nrrd_header metaimage_header dicom_mosaic dicom_frames c_api_session bridge_datagram)

(cd "$root" && cmake --preset fuzz -B "$build" >/dev/null)
cmake --build "$build" -j "$jobs" --target "${targets[@]/#/fuzz_}"

status=0
for t in "${targets[@]}"; do
  corpus="$build/corpus/$t"
  artifacts="$build/artifacts/$t"
  mkdir -p "$corpus" "$artifacts"
  echo "== fuzz_$t for ${seconds}s"
  if ! "$build/tools/fuzz/fuzz_$t" "$corpus" "$root/tools/fuzz/corpus/$t" \
      -max_total_time="$seconds" -max_len=4096 -timeout=10 -rss_limit_mb=2048 \
      -artifact_prefix="$artifacts/" -print_final_stats=1 2>"$build/fuzz_$t.log"; then
    echo "fuzz_$t: FOUND A PROBLEM (see $build/fuzz_$t.log and $artifacts)"
    tail -n 40 "$build/fuzz_$t.log"
    status=1
  else
    grep -E "^stat::(number_of_executed_units|new_units_added|peak_rss_mb)" "$build/fuzz_$t.log" || true
    grep -E "^Done [0-9]+ runs" "$build/fuzz_$t.log" || true
  fi
done
exit "$status"
