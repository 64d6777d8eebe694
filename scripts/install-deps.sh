#!/usr/bin/env bash
# Installs xi's build and run-time dependencies from Debian 12 packages.
# Idempotent: packages already present are skipped, apt-get runs only when something is missing.
# --bench adds what only bench/ uses: Embree (the ray-tracing ceiling) and matplotlib (plots);
# --mitsuba what bench/setup-mitsuba.sh needs beside them.
set -euo pipefail

packages=(
  build-essential cmake pkg-config
  pocl-opencl-icd ocl-icd-opencl-dev opencl-clhpp-headers opencl-c-headers clinfo
  libglm-dev nlohmann-json3-dev libopenexr-dev libassimp-dev libpng-dev zlib1g-dev
  libgtest-dev googletest
  assimp-testmodels  # the tests load its corpus of invalid model files
  libopenmpi-dev openmpi-bin  # `mpirun -np N xi render` (optional at build time: XI_WITH_MPI)
)
if [ "${1:-}" = "--bench" ]; then
  packages+=(libembree-dev python3-matplotlib python3-numpy)
elif [ "${1:-}" = "--mitsuba" ]; then
  # libllvm19: Dr.Jit's LLVM backend (Mitsuba's llvm_* variants); python3-venv: the venv that holds
  # Mitsuba from PyPI. (Meshes reach Mitsuba as xi's own triangles, through `xi export`.)
  packages=(libllvm19 python3-venv)
fi

missing=()
for p in "${packages[@]}"; do
  if ! dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed"; then
    missing+=("$p")
  fi
done

if [ ${#missing[@]} -eq 0 ]; then
  echo "install-deps: all ${#packages[@]} packages present"
  exit 0
fi

echo "install-deps: installing ${missing[*]}"
SUDO=""
if [ "$(id -u)" -ne 0 ]; then SUDO="sudo"; fi
export DEBIAN_FRONTEND=noninteractive
$SUDO apt-get update -qq
$SUDO apt-get install -y -qq --no-install-recommends "${missing[@]}"
