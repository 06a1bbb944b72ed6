"""The example third-party plugin (examples/block_on_pad), installed the way a user installs a
plugin (a built distribution whose entry point group ``cab`` names its module), works with nothing
in cab_core or plugins/ changed for it: its task runs through ``cab``, succeeds with the oracle and
fails idle; ``cab-plugins`` lists its task and observer; ``cab-suite-check`` checks the task; the
observer writes its CSV beside every attempt's records."""
from __future__ import annotations

import csv
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
EXAMPLE = ROOT / "examples" / "block_on_pad"
BIN = Path(sys.executable).parent


@pytest.fixture(scope="module")
def installed(tmp_path_factory) -> dict:
    """The example built and installed into a folder of its own (no edit of this environment):
    the environment for commands that see it, through its dist-info's entry points."""
    site = tmp_path_factory.mktemp("site")
    # built from a copy: setuptools writes its build folder beside the sources, and the source tree is
    # read by other tests at the same time (pytest-xdist workers)
    src = tmp_path_factory.mktemp("src") / EXAMPLE.name
    shutil.copytree(EXAMPLE, src, ignore=shutil.ignore_patterns("build", "*.egg-info"))
    r = subprocess.run([sys.executable, "-m", "pip", "install", "-q", "--no-deps",
                        "--target", str(site), str(src)], capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr
    assert list(site.glob("cab_example_block_on_pad-*.dist-info"))
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(filter(None, [str(site), os.environ.get("PYTHONPATH")])))
    return env


def run(args: list[str], env: dict, cwd: Path, timeout: int = 600) -> subprocess.CompletedProcess:
    return subprocess.run(args, capture_output=True, text=True, env=env, cwd=cwd, timeout=timeout)


def test_not_installed_the_task_is_unknown(tmp_path):
    r = run([str(BIN / "cab"), "task=block_on_pad", "model=idle", "sim=mujoco", "record.video=false"],
            dict(os.environ), tmp_path)
    assert r.returncode != 0
    assert "block_on_pad" in r.stderr


def test_cab_plugins_lists_its_task_and_observer(installed, tmp_path):
    r = run([str(BIN / "cab-plugins"), "--json"], installed, tmp_path)
    assert r.returncode == 0, r.stderr
    rows = {row["plugin"]: row for row in json.loads(r.stdout)}
    row = rows["example_block_on_pad"]
    assert row["distribution"] == "cab-example-block-on-pad"
    assert row["provides"]["task_suites"] == ["example_block_on_pad"]
    assert row["provides"]["record_observers"] == ["tcp_csv"]
    r = run([str(BIN / "cab-plugins")], installed, tmp_path)
    assert "block_on_pad" in r.stdout and "tcp_csv" in r.stdout


@pytest.mark.parametrize("model, success", [("oracle", True), ("idle", False)])
def test_its_task_through_cab(installed, tmp_path, model, success):
    out = tmp_path / "attempt"
    r = run([str(BIN / "cab"), "task=block_on_pad", f"+model={model}", "sim=mujoco", "record.video=false",
             f"hydra.run.dir={out}"], installed, tmp_path)
    assert r.returncode == 0, r.stderr[-2000:]
    result = json.loads((out / "result.json").read_text())
    assert result["task"] == "block_on_pad"
    assert result["instruction"] == "Pick up the red block and put it on the green pad, then let go."
    assert result["verdict"]["success"] is success
    assert set(result["verdict"]["predicates"]) == {"on_pad", "gripper_open"}
    assert "cab-example-block-on-pad" in json.dumps(result["versions"])
    # the observer's file: one row per call, in order, with both TCP positions
    with (out / "tcp_positions.csv").open() as f:
        rows = list(csv.DictReader(f))
    calls = [json.loads(line) for line in (out / "events.jsonl").read_text().splitlines()]
    calls = [e for e in calls if e["kind"] == "call"]
    assert [r["tool"] for r in rows] == [e["tool"] for e in calls]
    if model == "oracle":
        moved = [r for r in rows if r["tool"] in ("reach_tcp", "move_delta")]
        assert moved and all(r["left_z"] and r["right_z"] for r in moved)
        assert len({(r["left_x"], r["right_x"]) for r in moved}) > 3  # the positions change with the moves


def test_cab_suite_check_checks_its_task(installed, tmp_path):
    r = run([str(BIN / "cab-suite-check"), "--tasks", "block_on_pad", "--sim", "mujoco", "--jobs", "1",
             "--out", str(tmp_path / "check")], installed, tmp_path, timeout=900)
    assert r.returncode == 0, r.stdout[-2000:] + r.stderr[-2000:]
    assert "oracle: 1/1 successes within budgets; idle: 0/1 successes" in r.stdout
