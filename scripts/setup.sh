#!/usr/bin/env bash
# One command for a fresh machine: install everything, then run bare `cab` (the default task on
# SAPIEN on the CPU with the oracle agent). Extra arguments go to cab. PYTHON=python3.13 (or 3.12, or a
# path) sets it up on that interpreter (scripts/install.sh, docs/reference.md#python-versions).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/install.sh
. "${CAB_VENV:-.venv}/bin/activate"
cab "$@"
