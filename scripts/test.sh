#!/usr/bin/env bash
# Installs what the tests need, then runs them. Extra arguments go to pytest.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/install.sh
bash scripts/install-node-tools.sh   # MCP Inspector, Claude Code, Codex CLI: the MCP harness tests drive them
bash scripts/install-browser.sh      # Debian's chromium and chromedriver: the report's page in a headless browser
. .venv/bin/activate
# the habits the tree keeps: ruff over the whole tree, mypy over cab_core (their settings: pyproject.toml)
echo "ruff and mypy ..."
ruff check --quiet .
mypy --no-error-summary
set +e
# --cab-conformance: the conformance suites of cab_core.testing (its pytest plugin) over every installed
# simulator and task, as a plugin author runs them on theirs.
# pytest-xdist: one worker per CPU (CAB_TEST_WORKERS=N chooses; 0 runs the tests in this process); a worker
# takes a test file at a time, or one conformance check (tests/conftest.py)
python -m pytest -q -p no:cacheprovider --cab-conformance=all -n "${CAB_TEST_WORKERS:-$(nproc)}" --dist loadfile "$@"
rc=$?
set -e
if [ "$rc" -eq 5 ]; then
  echo "pytest collected no tests: treating as a failure" >&2
  exit 1
fi
exit "$rc"
