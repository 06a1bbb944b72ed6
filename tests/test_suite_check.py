"""CI runs the whole oracle suite: every installed task's reference solution succeeds within its
budgets (catalog seed, and seeds 1 and 2), attains its checkpoints, and the idle agent fails."""
import json
import os
import subprocess
import sys

import pytest

pytestmark = [pytest.mark.sim, pytest.mark.slow]
BIN = os.path.dirname(sys.executable)


def suite_check(tmp_path, *args):
    r = subprocess.run([os.path.join(BIN, "cab-suite-check"), "--out", str(tmp_path), *args],
                       capture_output=True, text=True, timeout=3000)
    summary = json.loads((tmp_path / "summary.json").read_text())
    return r, summary


def test_oracles_succeed_and_idle_fails_at_catalog_seeds(tmp_path):
    from cab_core.plugins import all_tasks

    r, s = suite_check(tmp_path)
    print(r.stdout)
    v = s["verdict"]
    n = len(all_tasks())
    assert v["oracle_attempts"] == n and v["idle_attempts"] == n
    failed = [(x["task"], x.get("error") or x.get("termination")) for x in s["rows"]
              if x["agent"] == "oracle" and not x.get("success")]
    assert failed == []
    assert v["oracle_success_within_budget"] == n
    assert v["idle_success"] == 0 and v["idle_subgoal_at_start"] == 0
    assert v["subgoals_attained"] == v["subgoals_total"]
    assert r.returncode == 0, r.stderr[-2000:]
    for line in ("oracle", "idle", "subgoals", "spatial", "ref"):
        assert line in r.stdout


def test_oracles_succeed_on_other_seeds(tmp_path):
    r, s = suite_check(tmp_path, "--seeds", "1,2", "--no-idle")
    failed = [(x["task"], x["seed"], x.get("error") or x.get("termination")) for x in s["rows"] if not x.get("success")]
    assert failed == []
    assert r.returncode == 0
