#!/usr/bin/env bash
# cab on each Python it supports: for every version of CAB_PYTHONS (default "3.11 3.12 3.13") found on
# PATH or under pyenv (scripts/find-python.sh), a venv of its own set up by scripts/install.sh
# (.cab_cache/py<version>/venv; what has no wheel is built once into .cab_cache/wheels, shared by every
# venv and by later runs), the core's fast tests (CAB_CHECK_TESTS) and one oracle attempt of click_bell
# per simulator (CAB_CHECK_SIMS). Prints a table; exit 1 if anything failed, or a version named in
# CAB_PYTHONS is missing (a version of the default list that is missing is skipped and said so).
# Each version's logs: .cab_cache/py<version>/{setup,tests}.log and attempts/<sim>/.
set -uo pipefail
cd "$(dirname "$0")/.."
PYTHONS="${CAB_PYTHONS:-3.11 3.12 3.13}"
SIMS="${CAB_CHECK_SIMS:-sapien pybullet mujoco}"
# the core's unit tests that start no cab process: configuration (Hydra's composition, the config
# schema, plugins' options), plugin loading, the run_code sandbox, the robot tools, statistics, margins,
# budgets, records, the import layering; about 2 min with 2 workers. The command line itself is the
# attempts below (test_cli*.py and test_plugin_loading.py start a cab per test: 6 min more)
TESTS="${CAB_CHECK_TESTS:-tests/test_config.py tests/test_config_plugins.py tests/test_cli_schema.py tests/test_plugins.py
  tests/test_sandbox.py tests/test_sandbox_policy.py tests/test_tools.py tests/test_stats.py tests/test_margins.py
  tests/test_budget.py tests/test_record.py tests/test_core_layout.py tests/test_pythons.py
  tests/test_leaderboard_export.py plugins/export_eee/tests/test_eee_export.py}"
WORKERS="${CAB_TEST_WORKERS:-$(nproc)}"

rows=()
failed=0
for v in $PYTHONS; do
  dir=".cab_cache/py$v"
  if ! exe=$(bash scripts/find-python.sh "$v" 2>/dev/null); then
    if [ -n "${CAB_PYTHONS:-}" ]; then failed=1; fi
    rows+=("$v|not found|-|-|$(printf -- '-|%.0s' $SIMS)")
    echo "Python $v: not found (PATH, pyenv)"
    continue
  fi
  mkdir -p "$dir"
  echo "Python $v ($exe): setting up $dir/venv ..."
  t0=$SECONDS
  # install.sh's own lines (a build from source, a venv recreated) pass through; the rest is in the log
  CAB_VENV="$dir/venv" PYTHON="$exe" bash scripts/install.sh >"$dir/setup.log" 2>&1
  rc=$?
  grep -E '^(building|recreating) ' "$dir/setup.log" | sed 's/^/  /'
  setup_s=$((SECONDS - t0))
  if [ "$rc" -ne 0 ]; then
    failed=1
    rows+=("$v|failed (${setup_s} s)|-|-|$(printf -- '-|%.0s' $SIMS)")
    echo "  set-up failed (exit $rc): $dir/setup.log"
    tail -3 "$dir/setup.log" | sed 's/^/  /'
    continue
  fi
  py="$dir/venv/bin/python"
  echo "  set up in ${setup_s} s; tests ..."
  t0=$SECONDS
  # shellcheck disable=SC2086
  "$py" -m pytest -q -p no:cacheprovider -n "$WORKERS" --dist loadfile --junitxml="$dir/tests.xml" $TESTS >"$dir/tests.log" 2>&1
  rc=$?
  tests_s=$((SECONDS - t0))
  # passed/total, and the warnings pytest summed up (a new DeprecationWarning on this Python shows here)
  counts=$("$py" - "$dir/tests.xml" "$dir/tests.log" <<'EOF'
import re, sys, xml.etree.ElementTree as ET
try:
    suites = ET.parse(sys.argv[1]).getroot().iter("testsuite")
except (OSError, ET.ParseError):
    print("no report|-"); sys.exit()
n = f = s = 0
for t in suites:
    n += int(t.get("tests", 0)); s += int(t.get("skipped", 0))
    f += int(t.get("failures", 0)) + int(t.get("errors", 0))
lines = open(sys.argv[2]).read().splitlines() or [""]
w = re.search(r"(\d+) warnings?", lines[-1])
print(f"{n - f - s}/{n - s}" + (f" ({s} skipped)" if s else "") + f"|{w.group(1) if w else 0}")
EOF
)
  [ "$rc" -eq 0 ] || failed=1
  echo "  tests: ${counts%|*} passed in ${tests_s} s (exit $rc)"
  cells=""
  for sim in $SIMS; do
    rm -rf "$dir/attempts/$sim"
    out=$("$dir/venv/bin/cab" task=click_bell "sim=$sim" "hydra.run.dir=$dir/attempts/$sim" 2>&1)
    rc=$?
    last=$(printf '%s\n' "$out" | tail -1)
    if [ "$rc" -eq 0 ] && [[ "$last" == *"success=True"* ]]; then
      verdict="success"
    elif [ "$rc" -eq 0 ]; then
      verdict="no success"; failed=1
    else
      verdict="error (exit $rc)"; failed=1
    fi
    echo "  $sim: $last"
    cells+="$verdict|"
  done
  rows+=("$v|${setup_s} s|${counts%|*}|${counts#*|}|$cells")
done

echo
header="python|set-up|tests passed|warnings|$(printf '%s|' $SIMS)"
{ echo "$header"; printf '%s\n' "${rows[@]}"; } | column -t -s '|'
exit "$failed"
