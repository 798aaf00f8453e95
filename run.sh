#!/usr/bin/env bash
# clrecon quick start: set up everything on a fresh Debian machine, then run one job.
#   bash run.sh demo [ARGS...]   render a built-in scene at 8 spp, reconstruct it, print time
#                                and quality, write images to out/
#   bash run.sh test [ARGS...]   run the test suite (pytest; benchmarks excluded)
#   bash run.sh setup [--platforms pocl,intel,oclgrind] [--icd-dir DIR]
#                                set up only, with the OpenCL platforms named (default: pocl;
#                                tools/setup_platforms.sh says how each is installed and
#                                registered; where not in /etc/OpenCL/vendors, the last line
#                                printed is the `export OCL_ICD_VENDORS=...` that selects them)
# Set-up: PoCL from Debian when no OpenCL platform is registered, a venv in .venv, the
# package (editable) with its test and eval extras. Idempotent; a second run is quick.
set -euo pipefail
cd "$(dirname "$0")"
VENV=${CLRECON_VENV:-.venv}
PY=${PYTHON:-python3}

# platforms first: a bad option fails before anything is installed
platform_env=
if [ "${1:-}" = setup ]; then
  platform_env=$(bash tools/setup_platforms.sh "${@:2}")
fi

need_root() { if [ "$(id -u)" = 0 ]; then "$@"; elif command -v sudo >/dev/null; then sudo "$@"; else
  echo "run.sh: need root to run: $*" >&2; exit 1; fi; }

if ! ls /etc/OpenCL/vendors/*.icd >/dev/null 2>&1; then
  echo "run.sh: no OpenCL platform registered; installing PoCL (CPU) from Debian" >&2
  need_root apt-get update -qq
  DEBIAN_FRONTEND=noninteractive need_root apt-get install -y -qq pocl-opencl-icd >/dev/null
fi
if ! "$PY" -c "import venv, ensurepip" >/dev/null 2>&1; then
  need_root apt-get update -qq
  DEBIAN_FRONTEND=noninteractive need_root apt-get install -y -qq python3-venv >/dev/null
fi
if [ ! -x "$VENV/bin/python" ]; then
  "$PY" -m venv "$VENV"
fi
stamp="$VENV/.clrecon-installed"
if [ ! -f "$stamp" ] || [ setup.cfg -nt "$stamp" ]; then
  "$VENV/bin/python" -m pip install -q --upgrade pip
  "$VENV/bin/python" -m pip install -q -e ".[test,eval]"
  touch "$stamp"
fi

cmd=${1:-demo}
shift || true
case "$cmd" in
  setup) if [ -n "$platform_env" ]; then echo "$platform_env"; fi ;;
  demo) exec "$VENV/bin/clrecon" demo "$@" ;;
  test) exec "$VENV/bin/python" -m pytest -q -n auto --dist loadfile "$@" ;;
  *) exec "$VENV/bin/clrecon" "$cmd" "$@" ;;
esac
