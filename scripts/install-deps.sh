#!/usr/bin/env bash
# Installs xi's dependencies from Debian 12 packages. Without options: what building and running the
# `xi` program needs (scripts/render-default.sh). --test adds what the test suite needs
# (scripts/build.sh, scripts/test.sh); --bench adds that and what only bench/ uses: Embree (the
# ray-tracing ceiling) and matplotlib (plots); --mitsuba installs only what bench/setup-mitsuba.sh
# needs beside them. Idempotent: packages already present are skipped, apt-get runs only when
# something is missing.
set -euo pipefail

xi=(
  build-essential cmake pkg-config
  pocl-opencl-icd ocl-icd-opencl-dev opencl-clhpp-headers opencl-c-headers
  libglm-dev nlohmann-json3-dev libopenexr-dev libassimp-dev libpng-dev zlib1g-dev
  libstb-dev  # stb_image: the textures of glTF and other assets (PNG, JPEG, Radiance .hdr)
)
test=(
  libgtest-dev googletest
  assimp-testmodels  # the tests load its models and its corpus of invalid model files
  libopenmpi-dev openmpi-bin  # `mpirun -np N xi render` (optional at build time: XI_WITH_MPI)
  clinfo
)
bench=(libembree-dev python3-matplotlib python3-numpy)
# libllvm19: Dr.Jit's LLVM backend (Mitsuba's llvm_* variants); python3-venv: the venv that holds
# Mitsuba from PyPI. (Meshes reach Mitsuba as xi's own triangles, through `xi export`.)
mitsuba=(libllvm19 python3-venv)

packages=("${xi[@]}")
for option in "$@"; do
  case "$option" in
    --test) packages+=("${test[@]}") ;;
    --bench) packages+=("${test[@]}" "${bench[@]}") ;;
    --mitsuba) packages=("${mitsuba[@]}") ;;
    *) echo "install-deps: unknown option '$option' (expected --test, --bench or --mitsuba)" >&2; exit 2 ;;
  esac
done

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
