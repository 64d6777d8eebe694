#!/usr/bin/env bash
# Sets up what bench/peers.py needs to run Mitsuba 3 beside xi. Idempotent: apt-get runs only for
# missing packages (scripts/install-deps.sh --mitsuba), the venv is created once and pip skips what
# is already installed.
#
#   bash bench/setup-mitsuba.sh
#
# - libllvm19: Dr.Jit's LLVM backend (Mitsuba's llvm_* variants) loads libLLVM at run time; Debian 12's
#   LLVM 19 is new enough for Dr.Jit, PoCL's LLVM 14/15 are not loaded into the same process.
# - python3-venv: the venv below (Mitsuba and numpy from PyPI, kept apart from Debian's python3), with
#   NVIDIA's flip-evaluator (HDR-FLIP) for bench/time_to_error.py.
# Prints the DRJIT_LIBLLVM_PATH that peers.py sets for Mitsuba (it finds it the same way).
set -euo pipefail

here="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
venv="$here/.venv"
mitsuba_version=3.9.1
flip_version=1.7

bash "$here/../scripts/install-deps.sh" --mitsuba

# Debian's own interpreter, not whatever python3 is first on the PATH (pyenv, another venv).
if [ ! -x "$venv/bin/python" ]; then
  echo "setup-mitsuba: creating $venv"
  /usr/bin/python3 -m venv "$venv"
fi
if ! "$venv/bin/python" -c "import mitsuba, numpy, flip_evaluator, sys; sys.exit(mitsuba.__version__ != '$mitsuba_version')" \
    2>/dev/null; then
  echo "setup-mitsuba: pip installing mitsuba==$mitsuba_version numpy flip-evaluator==$flip_version"
  "$venv/bin/python" -m pip install -q "mitsuba==$mitsuba_version" numpy "flip-evaluator==$flip_version"
fi

llvm="$(dpkg -L libllvm19 | grep -E '/libLLVM(-19)?\.so(\.[0-9.]+)?$' | head -n 1)"
if [ -z "$llvm" ]; then
  echo "setup-mitsuba: no libLLVM .so in the libllvm19 package" >&2
  exit 1
fi
echo "setup-mitsuba: mitsuba $("$venv/bin/python" -c 'import mitsuba; print(mitsuba.__version__)')," \
  "flip-evaluator $("$venv/bin/python" -m pip show flip-evaluator 2>/dev/null | sed -n 's/^Version: //p') in $venv"
echo "DRJIT_LIBLLVM_PATH=$llvm"
