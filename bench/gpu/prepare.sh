#!/usr/bin/env bash
# Packs, here, what bench/gpu/check.sh needs on a GPU machine lent by the `device` tool, into .gpu/
# (git-ignored). That machine has NVIDIA's driver, Python 3.12 with numpy and nothing else of ours: no
# Debian libraries, no Assimp models, no network. So this puts into .gpu/:
#   - the shared libraries of build/xi and build/xi_tests and an ICD file naming NVIDIA's OpenCL
#     (../shared/gpu/pack.sh, or $PACK);
#   - Mitsuba 3 and Dr.Jit for Python 3.12, unpacked and cut to the cuda_ad_rgb variant and the plugins
#     peers.py's conversion can use, as one .tar.xz (the whole Mitsuba wheel alone is 60 MB, near the
#     64 MiB that one call may carry);
#   - Assimp's test models that the suite and bench/scenes/engine.json read from /usr/share/assimp.
# It also makes bench/.cache/meshes hold the Assimp exports peers.py needs (no `assimp` tool there).
# usage, from anywhere, after bash scripts/build.sh:  bash bench/gpu/prepare.sh
set -euo pipefail
cd "$(dirname "$0")/../.."
PACK=${PACK:-../shared/gpu/pack.sh}
MITSUBA=${MITSUBA:-3.9.1} DRJIT=${DRJIT:-1.5.0}
for f in build/xi build/xi_tests; do
  [ -x "$f" ] || { echo "prepare: no $f: build first (bash scripts/build.sh)" >&2; exit 1; }
done
[ -f "$PACK" ] || { echo "prepare: no $PACK (set PACK to the GPU packing script)" >&2; exit 1; }
bash "$PACK" build/xi build/xi_tests

tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
echo "prepare: Mitsuba $MITSUBA and Dr.Jit $DRJIT wheels for CPython 3.12"
python3 -m pip download -q --no-deps --only-binary=:all: --python-version 3.12 --implementation cp \
  --platform manylinux_2_28_x86_64 --platform manylinux_2_27_x86_64 --platform manylinux_2_17_x86_64 \
  --platform manylinux2014_x86_64 -d "$tmp/wheels" "mitsuba==$MITSUBA" "drjit==$DRJIT"
site=$tmp/site
for w in "$tmp"/wheels/*.whl; do unzip -q -o "$w" -d "$site"; done
# Variants other than cuda_ad_rgb (scalar_rgb is Mitsuba's default, kept), headers, stubs, and the large
# plugins that no converted xi scene uses (peers.py convert(): ply shapes, diffuse/conductor/dielectric/
# twosided BSDFs, area and constant emitters, perspective camera, hdrfilm, box filter, path integrator).
(cd "$site/mitsuba" && rm -rf llvm_* cuda_ad_mono* cuda_ad_spectral* scalar_mono* scalar_spectral* \
  include cmake mitsuba_stubs && cd plugins && rm -f ellipsoids.so ellipsoidsmesh.so volpath.so \
  volpathmis.so bsplinecurve.so linearcurve.so sdfgrid.so sunsky.so timed_sunsky.so ptracer.so cylinder.so \
  principled.so principledthin.so roughplastic.so roughconductor.so roughdielectric.so hair.so measured.so \
  measured_polarized.so aov.so pplastic.so plastic.so envmap.so distant.so instance.so thinlens.so \
  projector.so spot.so gridvolume.so bumpmap.so normalmap.so blendbsdf.so orthographic.so specfilm.so \
  blender.so directionalarea.so serialized.so blendphase.so irradiancemeter.so radiancemeter.so)
rm -rf "$site"/drjit/include "$site"/drjit/cmake
find "$site" -name '*.pyi' -delete
tar -cJf .gpu/mitsuba-site.tar.xz -C "$site" .

mkdir -p .gpu/assimp-models/PLY .gpu/assimp-models/OBJ
cp -r /usr/share/assimp/models/glTF2 /usr/share/assimp/models/invalid .gpu/assimp-models/
cp /usr/share/assimp/models/PLY/cube.ply .gpu/assimp-models/PLY/
cp /usr/share/assimp/models/OBJ/cube_usemtl.obj /usr/share/assimp/models/OBJ/cube_usemtl.mtl \
  .gpu/assimp-models/OBJ/

# The Assimp exports of the bench scenes' meshes, as peers.py would make them.
/usr/bin/python3 - <<'PY'
import json, sys, tempfile
from pathlib import Path
sys.path.insert(0, "bench")
import peers
with tempfile.TemporaryDirectory() as tmp:
    for scene in ["bench/scenes/engine.json"]:
        for shape in json.loads(Path(scene).read_text())["shapes"]:
            if shape.get("type") == "mesh":
                peers.load_mesh(Path(scene).parent / shape["file"], tmp)
PY

carry=".gpu bench/.cache build/xi build/xi_tests"
bytes=$( (du -cb $carry | tail -1 | cut -f1; git ls-files -z | du -cb --files0-from=- | tail -1 | cut -f1) |
  awk '{s += $1} END {print s}')
echo "prepare: $((bytes / 1048576)) MiB travel (the device tool takes at most 64)"
echo "prepare: now call the device tool's run with carry [\".gpu\", \"bench/.cache\", \"build/xi\", \"build/xi_tests\"]"
echo "         and the command: bash bench/gpu/check.sh"
