#!/usr/bin/env bash
# Set-up + build + the whole test suite. This is the README's test command; .ci/run calls it.
#   bash tools/test.sh            Release build, all tests
#   PALP_PRESET=asan bash tools/test.sh   same with AddressSanitizer+UBSan (or tsan, debug)
set -euo pipefail
cd "$(dirname "$0")/.."
preset="${PALP_PRESET:-release}"
bash tools/setup.sh
# Tests skip an oracle that is missing (so the suite still runs elsewhere); here, where setup.sh
# installed them, a missing oracle is an error rather than a silent skip.
for tool in ccx dcm2niix gdcmconv gdcmdump unzip xvfb-run octave-cli psignifit Rscript; do
  command -v "$tool" >/dev/null || { echo "test.sh: oracle '$tool' missing after setup"; exit 1; }
done
[ -f /usr/share/psychtoolbox-3/Quest/QuestCreate.m ] ||
  { echo "test.sh: psychtoolbox-3-common (Quest) missing after setup"; exit 1; }
Rscript -e 'library(psyphy)' >/dev/null 2>&1 || { echo "test.sh: r-cran-psyphy missing after setup"; exit 1; }
/usr/bin/python3 -c "import nibabel" || { echo "test.sh: python3-nibabel missing after setup"; exit 1; }
/usr/bin/python3 -c "import vtkmodules.vtkRenderingOpenGL2" ||
  { echo "test.sh: python3-vtk9 missing after setup"; exit 1; }
# A fresh build directory (CI, a new clone) compiles the library modules as unity batches (less
# than half the CPU of one object per source); an existing one keeps its setting, so a developer's
# incremental rebuild still recompiles only the file that changed.
unity=()
[ -f "build/$preset/CMakeCache.txt" ] || unity=(-DPALP_UNITY_BUILD=ON)
cmake --preset "$preset" "${unity[@]}"
cmake --build --preset "$preset"
ctest --preset "$preset" "$@"
