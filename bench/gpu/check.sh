#!/usr/bin/env bash
# Checks on a GPU machine, from what bench/gpu/prepare.sh packed:
#   suite    the whole test suite on the GPU (but Install.* and MpiRender.*: no cmake or mpirun there)
#   profile  xi render --profile at 1920x1080, 64 spp, Cornell box and engine, three runs each
#   mitsuba  a 16-spp Mitsuba cuda_ad_rgb render of its own Cornell box, with Dr.Jit's log: shows the
#            backend starts before peers.py depends on it (a driver that never returns costs minutes)
#   peers    bench/peers.py --mitsuba-variant cuda_ad_rgb: the Cornell box at 256x256 (4096 spp), 512x512
#            (256 spp) and 1920x1080 (64 spp), the engine at the last two, the caustics scene at 128x128
#            (16384 spp); each group one run of peers.py (3 alternated runs after a warm-up)
# Each step has its own time limit and prints as it goes; everything printed is also in $OUT/check.txt.
# usage there:  bash bench/gpu/check.sh [STEP...]     (default: all four, in this order)
set -uo pipefail
cd "$(dirname "$0")/../.."
[ -f .gpu/env.sh ] && [ -f .gpu/mitsuba-site.tar.xz ] || { echo "check: run bash bench/gpu/prepare.sh here first" >&2; exit 2; }
source .gpu/env.sh
log=${OUT:-/tmp}/check.txt
all_steps="suite profile mitsuba peers"
steps=${*:-$all_steps}
for step in $steps; do
  [[ " $all_steps " == *" $step "* ]] || { echo "check: unknown step '$step' (one of: $all_steps)" >&2; exit 2; }
done
start=$(date +%s)
say() { echo "== $(( $(date +%s) - start )) s: $*" | tee -a "$log"; }
run() {  # LIMIT COMMAND...: the command, stopped after LIMIT seconds; a failure is named in the log
  local limit=$1; shift
  timeout "$limit" "$@" 2>&1 | tee -a "$log"
  local rc=${PIPESTATUS[0]}
  [ "$rc" = 0 ] || say "exit status $rc$([ "$rc" = 124 ] && echo " (stopped after $limit s)"): $*"
  return "$rc"
}

say "setup"
mkdir -p /usr/share/assimp/models && cp -r .gpu/assimp-models/. /usr/share/assimp/models/
mkdir -p /tmp/mitsuba-site /tmp/mitsuba-venv/bin && tar -xJf .gpu/mitsuba-site.tar.xz -C /tmp/mitsuba-site
# peers.py runs <venv>/bin/python; this machine's python3 may itself be a venv (with numpy), so a wrapper
# keeps it whole where a symbolic link would lose its site-packages.
printf '#!/bin/sh\nexec %s "$@"\n' "$(command -v python3)" >/tmp/mitsuba-venv/bin/python
chmod +x /tmp/mitsuba-venv/bin/python
export PYTHONPATH=/tmp/mitsuba-site PYTHONUNBUFFERED=1
nvidia-smi --query-gpu=name,driver_version,memory.total --format=csv,noheader | tee -a "$log"
build/xi devices 2>&1 | tee -a "$log"

mitsuba_ok=1
for step in $steps; do
  say "$step"
  case $step in
    suite)
      run 240 build/xi_tests --gtest_brief=1 --gtest_filter='-Install.*:MpiRender.*' ;;
    profile)
      for scene in scenes/cornell-box.json bench/scenes/engine.json; do for i in 1 2 3; do
        # the summary, the paths in flight and the per-stage table (not the per-bounce rows)
        run 60 bash -c "build/xi render $scene --resolution 1920x1080 --spp 64 --profile -o /tmp/profile.exr \
          2>&1 | grep -v '^ \+[0-9]'"
      done; done ;;
    mitsuba)
      run 120 python3 -c "
import time; t = time.time()
import drjit as dr; dr.set_log_level(dr.LogLevel.Info)
import mitsuba as mi; mi.set_variant('cuda_ad_rgb'); print('variant set', round(time.time() - t, 1), 's', flush=True)
img = mi.render(mi.load_dict(mi.cornell_box()), spp=16)
import numpy as np; print('rendered, mean', np.array(img).mean(), round(time.time() - t, 1), 's')" || mitsuba_ok=0 ;;
    peers)
      [ "$mitsuba_ok" = 1 ] || { say "peers skipped: Mitsuba's cuda_ad_rgb did not start"; continue; }
      peers="python3 bench/peers.py --mitsuba-variant cuda_ad_rgb --venv /tmp/mitsuba-venv --runs 3
        --worker-timeout 120 --out /tmp/peers"
      run 150 $peers --scenes cornell-box --resolution 256x256 --spp 4096
      run 150 $peers --scenes cornell-box,bench/scenes/engine.json --resolution 512x512 --spp 256
      run 150 $peers --scenes cornell-box,bench/scenes/engine.json --resolution 1920x1080 --spp 64
      run 150 $peers --scenes caustics --resolution 128x128 --spp 16384 ;;
  esac
done
say "done"
