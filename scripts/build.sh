#!/usr/bin/env bash
# Installs what is missing for xi and its tests, then configures build/ (Release, tests on) and
# builds every target. Arguments go to CMake's configure step.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/install-deps.sh --test
# A build/ first configured without MPI (scripts/render-default.sh installs only what `xi` needs)
# holds FindMPI's misses in its cache. CMake 3.25 looks again past them; forgetting them makes sure
# the Open MPI just installed is found whatever the version. XI_MPIEXEC is set once MPI is found.
forget=()
if [ -f build/CMakeCache.txt ] && ! grep -q '^XI_MPIEXEC:FILEPATH=/' build/CMakeCache.txt; then
  forget=(-U 'MPI*' -U XI_MPIEXEC)
fi
cmake -S . -B build -DCMAKE_BUILD_TYPE=Release -DXI_BUILD_TESTS=ON "${forget[@]}" "$@" >/dev/null
cmake --build build -j"$(nproc)"
