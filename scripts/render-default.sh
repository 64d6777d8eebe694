#!/usr/bin/env bash
# README command 1: install what `xi` needs, build only the `xi` program (no test suite), render the
# bundled Cornell box to cornell-box.exr/.png, then build the kernels any other scene's first image
# can start with (xi prebuild). Arguments go to `xi render`. scripts/test.sh adds the tests'
# packages and builds the rest into the same build/.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/install-deps.sh
cmake -S . -B build -DCMAKE_BUILD_TYPE=Release -DXI_BUILD_TESTS=OFF >/dev/null
cmake --build build -j"$(nproc)" --target xi
./build/xi render -o cornell-box.exr "$@"
./build/xi prebuild
