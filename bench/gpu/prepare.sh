#!/usr/bin/env bash
# Packs, on a Debian machine, what bench/gpu/check.sh needs on a GPU machine, into .gpu/ (git-ignored).
# That machine has NVIDIA's driver, Python 3.12 with numpy and nothing else of ours: no Debian
# libraries, no Assimp models, no network. So this puts into .gpu/:
#   - the shared libraries of build/xi and build/xi_tests and an ICD file naming NVIDIA's OpenCL
#     (bench/gpu/pack.sh, or the script $PACK names);
#   - Mitsuba 3 and Dr.Jit for Python 3.12, unpacked and cut to the cuda_ad_rgb variant and the plugins
#     bench/mitsuba_scene.py's conversion can use, as one .tar.xz (the whole Mitsuba wheel alone is 60 MB);
#   - Assimp's test models that the suite and bench/scenes/engine.json read from /usr/share/assimp.
# peers.py takes the scenes' triangles from build/xi there (`xi export`), so nothing else is needed.
# usage, from anywhere, after bash scripts/build.sh:  bash bench/gpu/prepare.sh
set -euo pipefail
cd "$(dirname "$0")/../.."
PACK=${PACK:-bench/gpu/pack.sh}
for f in build/xi build/xi_tests; do
  [ -x "$f" ] || { echo "prepare: no $f: build first (bash scripts/build.sh)" >&2; exit 1; }
done
[ -f "$PACK" ] || { echo "prepare: no $PACK (set PACK to the GPU packing script)" >&2; exit 1; }
bash "$PACK" build/xi build/xi_tests

# bench/.venv's pip fetches the wheels (idempotent, as for peers.py).
bash bench/setup-mitsuba.sh >/dev/null
# the same Mitsuba and Dr.Jit as the CPU bench's venv
read -r MITSUBA DRJIT < <(bench/.venv/bin/python -c 'import mitsuba, drjit; print(mitsuba.__version__, drjit.__version__)')
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
echo "prepare: Mitsuba $MITSUBA and Dr.Jit $DRJIT wheels for CPython 3.12"
bench/.venv/bin/python -m pip download -q --no-deps --only-binary=:all: --python-version 3.12 \
  --implementation cp --platform manylinux_2_28_x86_64 --platform manylinux_2_27_x86_64 \
  --platform manylinux_2_17_x86_64 --platform manylinux2014_x86_64 -d "$tmp/wheels" \
  "mitsuba==$MITSUBA" "drjit==$DRJIT"
/usr/bin/python3 - "$tmp" <<'PY'
# Unpacks both wheels, keeps the cuda_ad_rgb variant (and scalar_rgb, Mitsuba's default), drops headers,
# stubs and the large plugins no converted xi scene uses (mitsuba_scene.convert(): ply shapes, diffuse,
# conductor, dielectric and twosided BSDFs, area and constant emitters, perspective camera, hdrfilm, box
# filter, path integrator), and writes the rest as one .tar.xz.
import shutil, sys, tarfile, zipfile
from pathlib import Path
tmp = Path(sys.argv[1])
site = tmp / "site"
for wheel in sorted((tmp / "wheels").glob("*.whl")):
    zipfile.ZipFile(wheel).extractall(site)
unused_plugins = """ellipsoids ellipsoidsmesh volpath volpathmis bsplinecurve linearcurve sdfgrid sunsky
    timed_sunsky ptracer cylinder principled principledthin roughplastic roughconductor roughdielectric hair
    measured measured_polarized aov pplastic plastic envmap distant instance thinlens projector spot
    gridvolume bumpmap normalmap blendbsdf orthographic specfilm blender directionalarea serialized
    blendphase irradiancemeter radiancemeter""".split()
drop = [site / "mitsuba" / "plugins" / f"{p}.so" for p in unused_plugins]
for pattern in ["llvm_*", "cuda_ad_mono*", "cuda_ad_spectral*", "scalar_mono*", "scalar_spectral*"]:
    drop += (site / "mitsuba").glob(pattern)
drop += [site / d for d in ["mitsuba/include", "mitsuba/cmake", "mitsuba/mitsuba_stubs", "drjit/include",
                            "drjit/cmake"]]
drop += site.rglob("*.pyi")
for path in drop:
    if path.is_dir():
        shutil.rmtree(path)
    elif path.exists():
        path.unlink()
with tarfile.open(".gpu/mitsuba-site.tar.xz", "w:xz") as tar:
    for path in sorted(site.iterdir()):
        tar.add(path, arcname=path.name)
PY

mkdir -p .gpu/assimp-models/PLY .gpu/assimp-models/OBJ
cp -r /usr/share/assimp/models/glTF2 /usr/share/assimp/models/invalid .gpu/assimp-models/
cp /usr/share/assimp/models/PLY/cube.ply .gpu/assimp-models/PLY/
cp /usr/share/assimp/models/OBJ/cube_usemtl.obj /usr/share/assimp/models/OBJ/cube_usemtl.mtl \
  .gpu/assimp-models/OBJ/

carry=".gpu build/xi build/xi_tests"
bytes=$( (du -cb $carry | tail -1 | cut -f1; git ls-files -z | du -cb --files0-from=- | tail -1 | cut -f1) |
  awk '{s += $1} END {print s}')
echo "prepare: $((bytes / 1048576)) MiB to copy: the tracked files and $carry"
echo "prepare: then, on the GPU machine, in that copy: bash bench/gpu/check.sh"
