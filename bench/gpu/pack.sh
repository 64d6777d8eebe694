#!/usr/bin/env bash
# Packs what a GPU machine without Debian's libraries needs to run a build of xi made here.
# That machine has NVIDIA's driver (with its OpenCL library) but no package registry and none of
# Debian's libraries, so this copies the shared libraries the given binaries link (all but the C and
# C++ runtime) and an OpenCL ICD file naming NVIDIA's driver into .gpu/ of the project root
# (git-ignored), with .gpu/env.sh to source there.
# usage, from the project root after building:  bash bench/gpu/pack.sh build/xi build/xi_tests ...
set -euo pipefail
[ $# -ge 1 ] || { echo "usage: pack.sh BINARY..." >&2; exit 2; }
rm -rf .gpu && mkdir -p .gpu/lib .gpu/icd
echo libnvidia-opencl.so.1 > .gpu/icd/nvidia.icd
for bin in "$@"; do
  ldd "$bin" | awk '$3 ~ /^\// {print $3}' | while read -r lib; do
    case "$(basename "$lib")" in
      libc.so*|libm.so*|libdl.so*|librt.so*|libpthread.so*|libstdc++.so*|libgcc_s.so*|ld-linux*) ;;
      *) cp -Lu "$lib" .gpu/lib/ ;;
    esac
  done
done
cat > .gpu/env.sh <<'ENV'
# Source on the GPU machine from the project root: the packed libraries first, then the driver's.
export LD_LIBRARY_PATH=$PWD/.gpu/lib:${LD_LIBRARY_PATH:-}:/usr/local/nvidia/lib64:/usr/local/nvidia/lib
export OCL_ICD_VENDORS=$PWD/.gpu/icd
export XI_CACHE_DIR=/tmp/xi-cache
ENV
du -sh .gpu | sed 's/^/packed: /'
