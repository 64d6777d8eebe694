#!/usr/bin/env bash
# Render benchmark: the Cornell box at 512x512, 16 spp with --profile, N times (default 5), plus the
# kernel load from the binary cache and a 256x256 reference measured in the same run. Prints medians
# of seconds, Msamples/s, Mrays/s, extend Mitems/s and each stage's time and share.
#
#   bench/bench_render.sh [XI_BINARY (default build/xi)] [RUNS (default 5)]
#
# Builds nothing: build xi first (cmake --build build). Needs python3 (standard library only);
# the parsing and medians are in bench_render.py beside this script.
set -euo pipefail

here="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
xi="${1:-build/xi}"
runs="${2:-5}"

if ! command -v python3 >/dev/null; then
  echo "bench: python3 is needed" >&2
  exit 1
fi
if [[ ! -x "$xi" ]]; then
  echo "bench: $xi is not an executable (build xi first, or pass its path)" >&2
  exit 1
fi
if ! [[ "$runs" =~ ^[1-9][0-9]*$ ]]; then
  echo "bench: RUNS must be a positive whole number, got '$runs'" >&2
  exit 1
fi

exec python3 "$here/bench_render.py" "$xi" "$runs"
