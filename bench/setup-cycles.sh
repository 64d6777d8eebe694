#!/usr/bin/env bash
# Sets up what bench/time_to_error.py needs to run Blender's Cycles beside xi: PyPI's bpy (Blender as
# a Python module) in its own venv, bench/.venv-bpy. Idempotent: apt-get runs only for missing
# packages, the venv is created once and pip skips what is already installed.
#
#   bash bench/setup-cycles.sh
#
# - bpy 5.0.1 is built for CPython 3.11 only: Debian 12's /usr/bin/python3 is 3.11, so the venv is
#   made from it (another python3 on the PATH, pyenv or a venv, may be another version).
# - bpy is a whole Blender: it links X11 and GL libraries even without a display (libx11-6 ...
#   libgl1 below: what its module links, and libxxf86vm1, which Blender loads); `import bpy` names
#   the first one missing.
# - python3-venv: the venv itself.
# Prints bpy's version and build and the Cycles devices it sees.
set -euo pipefail

here="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
venv="$here/.venv-bpy"
bpy_version=5.0.1
python=/usr/bin/python3
libraries=(python3-venv libx11-6 libxext6 libxrender1 libxxf86vm1 libxfixes3 libxi6 libxkbcommon0 libsm6 libgl1)

missing=()
for p in "${libraries[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "ok installed" || missing+=("$p")
done
if [ ${#missing[@]} -gt 0 ]; then
  echo "setup-cycles: installing ${missing[*]}"
  apt_get=(apt-get)
  [ "$(id -u)" -eq 0 ] || apt_get=(sudo apt-get)
  "${apt_get[@]}" update -q
  DEBIAN_FRONTEND=noninteractive "${apt_get[@]}" install -y -q "${missing[@]}"
fi

version="$("$python" -c 'import sys; print("%d.%d" % sys.version_info[:2])')"
if [ "$version" != 3.11 ]; then
  echo "setup-cycles: bpy $bpy_version needs Python 3.11; $python is $version" >&2
  exit 1
fi
if [ ! -x "$venv/bin/python" ]; then
  echo "setup-cycles: creating $venv"
  "$python" -m venv "$venv"
fi
if ! "$venv/bin/python" -c "import bpy, numpy, sys; sys.exit(bpy.app.version_string.split()[0] != '$bpy_version')" \
    2>/dev/null; then
  echo "setup-cycles: pip installing bpy==$bpy_version numpy (about 400 MB)"
  "$venv/bin/python" -m pip install -q "bpy==$bpy_version" numpy
fi

"$venv/bin/python" - <<'EOF'
import bpy
prefs = bpy.context.preferences.addons["cycles"].preferences
devices = [f"{d.name} ({d.type})" for d in prefs.get_devices_for_type("CPU")]
print(f"setup-cycles: bpy {bpy.app.version_string} (built {bpy.app.build_date.decode()}, "
      f"{bpy.app.build_hash.decode()}); Cycles devices: {', '.join(devices)}")
EOF
