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


# every simulator CI runs the oracle suite on, at the catalog seeds
SIMS = ["sapien", "pybullet", "mujoco"]


@pytest.mark.parametrize("sim", SIMS)
def test_oracles_succeed_and_idle_fails_at_catalog_seeds(tmp_path, sim):
    from cab_core.plugins import all_tasks

    r, s = suite_check(tmp_path, "--sim", sim)
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


def test_cross_simulator_table(tmp_path):
    """Several simulators: the same attempts on each, and a per-task, per-simulator table."""
    r, s = suite_check(tmp_path, "--sim", "sapien,pybullet", "--tasks", "click_bell", "--jobs", "2")
    assert s["sims"] == ["sapien", "pybullet"]
    assert sorted((x["sim"], x["agent"]) for x in s["rows"]) == [
        ("pybullet", "idle"), ("pybullet", "oracle"), ("sapien", "idle"), ("sapien", "oracle")]
    cells = s["cross_sim"]["click_bell"]
    for sim in ("sapien", "pybullet"):
        assert cells[sim]["success"] is True and cells[sim]["calls"] > 0, cells
        assert 0 < cells[sim]["sim_s"] and 0 < cells[sim]["wall_s"], cells
        assert s["verdict_by_sim"][sim]["oracle_success_within_budget"] == 1
    assert "result  calls   sim s  wall s" in r.stdout
    assert r.returncode == 0, r.stderr[-2000:]


def test_unknown_simulator_is_refused(tmp_path):
    r = subprocess.run([os.path.join(BIN, "cab-suite-check"), "--out", str(tmp_path), "--sim", "no_such_sim"],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 2 and "no_such_sim" in r.stderr
