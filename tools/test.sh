#!/usr/bin/env bash
# Set-up + build + the whole test suite. This is the README's test command; .ci/run calls it.
#   bash tools/test.sh            Release build, all tests
#   PALP_PRESET=asan bash tools/test.sh   same with AddressSanitizer+UBSan (or tsan, debug)
set -euo pipefail
cd "$(dirname "$0")/.."
preset="${PALP_PRESET:-release}"
bash tools/setup.sh
cmake --preset "$preset"
cmake --build --preset "$preset"
ctest --preset "$preset" "$@"
