#!/usr/bin/env bash
# Installs xi's dependencies from Debian 12 packages. Without options: what building and running the
# `xi` program needs (scripts/render-default.sh). --test adds what the test suite needs
# (scripts/build.sh, scripts/test.sh); --bench adds that and what only bench/ uses: Embree (the
# ray-tracing ceiling) and matplotlib (plots); --mitsuba installs only what bench/setup-mitsuba.sh
# needs beside them. --denoise adds Intel Open Image Denoise 2 (OIDN) for `xi render --denoise` and
# `xi denoise`: the shared libraries of PyPI's pyoidn wheel (OIDN 2.5.1 with its CPU, CUDA, HIP and
# SYCL device modules and TBB) unpacked into build/oidn/lib, where xi looks for them, or into
# $XI_OIDN_PATH if that is set. Idempotent: packages already present are skipped, apt-get runs only
# when something is missing, and OIDN is fetched only when its folder lacks it.
set -euo pipefail
root="$(cd "$(dirname "$0")/.." && pwd)"

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
denoise=(python3-pip)  # pip download fetches the wheel

packages=("${xi[@]}")
with_oidn=0
for option in "$@"; do
  case "$option" in
    --test) packages+=("${test[@]}") ;;
    --bench) packages+=("${test[@]}" "${bench[@]}") ;;
    --mitsuba) packages=("${mitsuba[@]}") ;;
    --denoise) packages+=("${denoise[@]}"); with_oidn=1 ;;
    *) echo "install-deps: unknown option '$option' (expected --test, --bench, --mitsuba or --denoise)" >&2; exit 2 ;;
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
else
  echo "install-deps: installing ${missing[*]}"
  SUDO=""
  if [ "$(id -u)" -ne 0 ]; then SUDO="sudo"; fi
  export DEBIAN_FRONTEND=noninteractive
  $SUDO apt-get update -qq
  $SUDO apt-get install -y -qq --no-install-recommends "${missing[@]}"
fi

[ "$with_oidn" -eq 1 ] || exit 0
# OIDN from the pyoidn wheel, pinned by version and hash. Its libraries find each other through
# their RPATH $ORIGIN/../lib, so the folder they go to must be named lib. A wheel holds no symlinks
# (libOpenImageDenoise.so, .so.2 and .so.2.5.1 are three copies), so each copy becomes a link to
# the file with the longest name again, as OIDN's own release lays them out.
oidn_dir="${XI_OIDN_PATH:-$root/build/oidn/lib}"
oidn_wheel="pyoidn==2.5.1.0 --hash=sha256:32ad13368f8de1ef63001942ad05b02a00cd732d1206d97f352d3a3f606d823e"
stamp="$oidn_dir/.installed-pyoidn-2.5.1.0"
if [ -f "$stamp" ]; then
  echo "install-deps: OIDN 2.5.1 present in $oidn_dir"
  exit 0
fi
if [ "$(basename "$oidn_dir")" != lib ]; then
  echo "install-deps: XI_OIDN_PATH=$oidn_dir: OIDN's libraries must go to a folder named lib" >&2
  exit 2
fi
download="$(mktemp -d)"
trap 'rm -rf "$download"' EXIT
echo "$oidn_wheel" > "$download/requirements.txt"
echo "install-deps: downloading OIDN 2.5.1 (PyPI: pyoidn 2.5.1.0, 88 MB) into $oidn_dir"
/usr/bin/python3 -m pip download --quiet --disable-pip-version-check --no-deps --only-binary=:all: \
  --require-hashes -r "$download/requirements.txt" -d "$download"
mkdir -p "$oidn_dir"
/usr/bin/python3 - "$download"/pyoidn-*.whl "$oidn_dir" <<'PY'
import filecmp, os, sys, zipfile
wheel, dest = sys.argv[1], sys.argv[2]
prefix = "pyoidn/oidn/lib/"
with zipfile.ZipFile(wheel) as z:
    names = [n for n in z.namelist() if n.startswith(prefix) and "/" not in n[len(prefix):] and ".so" in n]
    for n in names:
        with z.open(n) as src, open(os.path.join(dest, n[len(prefix):]), "wb") as out:
            out.write(src.read())
libs = sorted((n[len(prefix):] for n in names), key=len, reverse=True)
for name in libs:  # libfoo.so.2 -> libfoo.so.2.5.1 where they are the same file
    longer = [l for l in libs if l.startswith(name + ".") and not os.path.islink(os.path.join(dest, l))]
    if longer and filecmp.cmp(os.path.join(dest, name), os.path.join(dest, longer[0]), shallow=False):
        os.remove(os.path.join(dest, name))
        os.symlink(longer[0], os.path.join(dest, name))
for name in libs:
    if not os.path.islink(os.path.join(dest, name)):
        os.chmod(os.path.join(dest, name), 0o755)
PY
touch "$stamp"
echo "install-deps: OIDN 2.5.1 installed in $oidn_dir ($(du -sh "$oidn_dir" | cut -f1))"
