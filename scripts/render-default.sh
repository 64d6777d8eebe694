#!/usr/bin/env bash
# README command 1: install what is missing, build, render the bundled Cornell box to cornell-box.exr/.png.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/build.sh
./build/xi render -o cornell-box.exr "$@"
