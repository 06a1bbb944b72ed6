"""cab-suite-check: every installed task's reference solution succeeds within its budgets at seeds 1
and 2; several simulators side by side; seed sets and perturbed runs; mistakes. At the catalog seeds,
every task on every simulator (the oracle succeeds, the idle agent fails) is a check of the
conformance plugin: ``pytest --cab-conformance`` (scripts/test.sh turns it on)."""
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from cab_core.testing.task_conformance import recorded_margins_agree

pytestmark = [pytest.mark.sim, pytest.mark.slow]
BIN = os.path.dirname(sys.executable)


def suite_check(tmp_path, *args):
    r = subprocess.run([os.path.join(BIN, "cab-suite-check"), "--out", str(tmp_path), *args],
                       capture_output=True, text=True, timeout=3000)
    summary = json.loads((tmp_path / "summary.json").read_text())
    return r, summary


def check_recorded_margins(rows):
    for x in rows:
        recorded_margins_agree(x)


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
    for line in ("oracle", "idle", "subgoals", "spatial", "ref", "margin"):
        assert line in r.stdout
    check_recorded_margins(s["rows"])
    assert r.returncode == 0, r.stderr[-2000:]


def test_seed_set_and_perturbed_runs(tmp_path):
    """--seed-set takes each task's own seeds; --perturb N runs each oracle N times under noise
    (recorded in result.json) and reports a success rate and smallest margin per task and simulator."""
    from cab_core.plugins import all_tasks

    heldout = all_tasks()["click_bell"].seeds("heldout")
    assert len(heldout) >= 20 and all_tasks()["click_bell"].info.seed not in heldout
    r, s = suite_check(tmp_path, "--sim", "mujoco", "--tasks", "click_bell", "--seed-set", "heldout", "--perturb", "2",
                       "--jobs", "2")
    assert r.returncode == 0, r.stdout[-2000:] + r.stderr[-2000:]
    assert sorted((x["seed"], x["perturb"]) for x in s["rows"]) == sorted((h, k) for h in heldout for k in (1, 2))
    cell = s["robustness"]["click_bell"]["mujoco"]
    assert cell["runs"] == 2 * len(heldout) and cell["successes"] == cell["runs"] and 0 < cell["min_margin"] <= 1
    records = [json.loads((Path(x["dir"]) / "result.json").read_text()) for x in s["rows"]]
    drawn = {(rec["seed"], rec["perturbation"]["seed"]): rec["perturbation"]["objects"]["bell"] for rec in records}
    assert len({round(o["dx_m"], 9) for o in drawn.values()}) == len(drawn)  # each run its own noise
    assert all(abs(o["dx_m"]) <= 1e-3 and abs(o["yaw_deg"]) <= 0.5 and abs(o["mass_scale"] - 1) <= 0.02
               for o in drawn.values())
    check_recorded_margins(s["rows"])
    assert "min " in r.stdout and "under perturbation" in r.stdout


def test_seed_set_mistakes_are_one_line(tmp_path):
    r = subprocess.run([os.path.join(BIN, "cab-suite-check"), "--out", str(tmp_path), "--tasks", "click_bell",
                        "--seed-set", "no_such_set"], capture_output=True, text=True, timeout=300)
    assert r.returncode == 2
    assert r.stderr.strip() == ("cab-suite-check: task click_bell has no seed set 'no_such_set'; "
                                "its sets: catalog, heldout")


def test_unknown_simulator_is_refused(tmp_path):
    r = subprocess.run([os.path.join(BIN, "cab-suite-check"), "--out", str(tmp_path), "--sim", "no_such_sim"],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 2 and "no_such_sim" in r.stderr
