#!/usr/bin/env bash
# README command 2: install what is missing (the tests' packages too), build everything, run the
# whole test suite with ctest; then the device-free tests and the fuzz driver again under the
# sanitizers (build-asan/).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/install-deps.sh --denoise  # OIDN into build/oidn/lib, for the denoising tests
bash scripts/build.sh
cd build
ctest --output-on-failure -j"$(nproc)" --timeout 900
cd ..

# The host code again under AddressSanitizer and UBSan (XI_SANITIZE), in its own build folder: the
# tests that open no OpenCL device (CMakeLists.txt lists their suites; PoCL is not ASan-clean, so
# device tests stay out) and the fuzz driver. A sanitizer report fails its test, and so this script.
# -O1 (AddressSanitizer's own advice) and line tables only (-g1: its reports still name file and line)
# build in half the time of RelWithDebInfo's -O2 -g, and the tests run about as fast.
cmake -S . -B build-asan -DCMAKE_BUILD_TYPE=RelWithDebInfo "-DCMAKE_CXX_FLAGS_RELWITHDEBINFO=-O1 -g1 -DNDEBUG" \
  -DXI_SANITIZE=ON >/dev/null
cmake --build build-asan -j"$(nproc)" --target xi_tests xi_fuzz
ctest --test-dir build-asan --output-on-failure -j"$(nproc)" --timeout 900
