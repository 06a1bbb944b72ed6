#!/usr/bin/env bash
# One command for a fresh machine: install everything, then run bare `cab` (the default task on
# SAPIEN on the CPU with the oracle agent). Extra arguments go to cab.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/install.sh
. .venv/bin/activate
cab "$@"
