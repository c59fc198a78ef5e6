#!/usr/bin/env bash
# Installs every Debian package palp needs to build, test and benchmark.
# The one place where dependencies are listed. Safe to run again: it installs only what is missing.
set -euo pipefail

PACKAGES=(
  # build
  cmake g++ ninja-build pkg-config git clang-format
  # libraries
  libeigen3-dev libopenvdb-dev libboost-iostreams-dev libembree-dev libtbb-dev
  libgdcm-dev libopenjp2-7-dev libnifti2-dev zlib1g-dev libpng-dev libcairo2-dev
  libsuitesparse-dev libcli11-dev nlohmann-json3-dev libtinyobjloader-dev libassimp-dev
  libgtest-dev libgmock-dev libbenchmark-dev
  # an optimised single-threaded BLAS/LAPACK behind libblas.so.3 for CHOLMOD's supernodal
  # factorisations (the secondary region): `palp sweep` of cube13.json takes 14 % less CPU
  libopenblas0-serial
  # Python bindings (python/): pybind11 and Debian's Python headers
  pybind11-dev python3-dev
  # OpenIGTLink v2 stream of `palp serve --igtl-port` (optional: built when found)
  libopenigtlink-dev
  # oracles and baselines used by tests and benchmarks
  dcm2niix calculix-ccx rt-tests libgdcm-tools unzip time
  python3-openvdb python3-nibabel python3-pydicom python3-numpy
  # the VTK viewer example (tools/examples/viewer.py) and its off-screen test under Xvfb
  python3-vtk9 xvfb xauth
  # error-analysis sweeps (palp sweep / errormap): Philox streams, MPI, a one-node Slurm for the
  # cluster test, and the OpenTURNS / scipy oracles of the partial rank correlations
  librandom123-dev libopenmpi-dev openmpi-bin slurm-wlm munge python3-openturns python3-scipy
  # perception studies (haptics/perception): QUEST against Psychtoolbox's Quest*.m under Octave,
  # psychometric fits against psignifit 2.5.6 and R's psyphy
  octave psychtoolbox-3-common psignifit r-cran-psyphy
  # fuzzing (clang's libFuzzer)
  clang libfuzzer-14-dev libclang-rt-14-dev
)

missing=()
for p in "${PACKAGES[@]}"; do
  if ! dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed"; then
    missing+=("$p")
  fi
done

if ((${#missing[@]} == 0)); then
  echo "setup: all ${#PACKAGES[@]} packages present"
  exit 0
fi

echo "setup: installing ${#missing[@]} packages: ${missing[*]}"
SUDO=""
if [[ $(id -u) -ne 0 ]]; then SUDO="sudo"; fi
export DEBIAN_FRONTEND=noninteractive
$SUDO apt-get update -qq
$SUDO apt-get install -y -qq --no-install-recommends "${missing[@]}"
