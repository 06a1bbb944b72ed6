"""Where attempts land: every swept value that varies names a folder (simulator included), two jobs
of one sweep that would share a folder are refused before anything runs, a sweep directory of the
first layout is refused rather than run again elsewhere, and cab-report counts what a sweep over the
three simulators wrote."""
from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
from hydra import compose, initialize_config_module

import cab_core.apps.cli  # noqa: F401  (registers the resolvers)
from cab_core.sweep.layout import path_safe, swept_component, varying_keys
from cab_core.sweep.manifest import MANIFEST, fingerprint

BIN = os.path.dirname(sys.executable)
CAB = os.path.join(BIN, "cab")


def cab_m(sweep_dir: Path, *overrides: str, timeout: int = 600) -> subprocess.CompletedProcess:
    return subprocess.run([CAB, "-m", "task=click_bell", *overrides, f"hydra.sweep.dir={sweep_dir}"],
                          cwd=sweep_dir.parent, capture_output=True, text=True, timeout=timeout)


def result_dirs(sweep_dir: Path) -> list[str]:
    return sorted(str(p.parent.relative_to(sweep_dir)) for p in sweep_dir.rglob("result.json"))


# -- naming ---------------------------------------------------------------------------------------

def test_swept_folder_names_each_varying_key_path_safe_and_injective():
    assert varying_keys([["attempt=1", "budget.tool_calls=3", "sim=pybullet", "+sandbox.mode=off"],
                         ["attempt=2", "budget.tool_calls=5", "sim=mujoco", "+sandbox.mode=off"]]) == \
        ["budget.tool_calls"]  # sim and attempt have folders of their own; sandbox.mode does not vary
    job = ["task=click_bell", "sim.physics.impratio=20", "budget.tool_calls=5", "record.video=False"]
    assert swept_component(job, ["sim.physics.impratio", "budget.tool_calls"]) == \
        "budget.tool_calls=5,sim.physics.impratio=20/"
    assert swept_component(job, []) == ""
    assert swept_component(["model.base_url=http://h:1/v1"], ["model.base_url"]) == \
        "model.base_url=http%3A%2F%2Fh%3A1%2Fv1/"
    # separators inside values are encoded, so different values never share a folder
    assert path_safe("a,b=c") == "a%2Cb%3Dc" and path_safe("a%2Cb") == "a%252Cb"
    assert swept_component(["x=a,y=b"], ["x", "y"]) != swept_component(["x=a%2Cy%3Db"], ["x", "y"])
    long = swept_component([f"model.prompt={'p' * 400}"], ["model.prompt"])
    assert len(long.encode()) <= 201 and long.endswith("/") and "/" not in long[:-1]
    assert long != swept_component([f"model.prompt={'p' * 399}q"], ["model.prompt"])


def test_single_run_folder_names_the_simulator():
    with initialize_config_module(version_base=None, config_module="cab_core.conf"):
        cfg = compose(config_name="config", overrides=["task=click_bell", "model=idle", "sim=mujoco"],
                      return_hydra_config=True)
    parts = cfg.hydra.run.dir.split("/")
    assert parts[:4] == ["outputs", "click_bell", "idle", "mujoco"] and len(parts) == 5


@pytest.mark.sim
def test_swept_key_names_its_folder_and_resumes(tmp_path):
    sweep = tmp_path / "sw"
    args = ("model=idle", "sim=pybullet", "record.video=false", "record.video_size=[32,24],[16,12]", "hydra.launcher.n_jobs=2")
    r = cab_m(sweep, *args)
    assert r.returncode == 0, r.stderr[-3000:]
    base = "click_bell/idle/pybullet"
    want = {f"{base}/record.video_size=%5B32%2C24%5D/seed-0/attempt-1": [32, 24],
            f"{base}/record.video_size=%5B16%2C12%5D/seed-0/attempt-1": [16, 12]}
    assert result_dirs(sweep) == sorted(want)
    for d, size in want.items():  # each folder holds the attempt it names
        assert f"record.video_size=[{size[0]},{size[1]}]" in (sweep / d / ".hydra" / "overrides.yaml").read_text()
    m = json.loads((sweep / MANIFEST).read_text())
    assert m["manifest_version"] == "cab-sweep/2" and m["path_keys"] == ["record.video_size"]
    assert sorted(m["folders"]) == sorted(want)
    assert m["fingerprint"] == fingerprint(m["config"], m["jobs"])
    assert r.stderr.splitlines()[-1] == f"cab sweep: 2/2 attempts complete; {sweep}"
    again = cab_m(sweep, *args)
    assert again.returncode == 0, again.stderr[-3000:]
    skipped = sorted(line.split("] ", 1)[1].split(":", 1)[0] for line in again.stderr.splitlines()
                     if line.endswith("complete already, skipped | sweep complete"))
    assert skipped == sorted(want)
    assert len(json.loads((sweep / MANIFEST).read_text())["sessions"]) == 2


# -- refusals -------------------------------------------------------------------------------------

@pytest.mark.parametrize("overrides, first, second, folder", [
    (["model=idle", "seed=null,0"], "seed=0", "seed=null", "click_bell/idle/pybullet/seed-0/attempt-1"),
    (["model=idle", "attempt=1,1"], "attempt=1", "attempt=1", "click_bell/idle/pybullet/seed-0/attempt-1"),
    (["model=idle,idle_again"], "model=idle", "model=idle_again", "click_bell/idle/pybullet/seed-0/attempt-1"),
])
def test_jobs_sharing_a_folder_are_refused_before_anything_runs(tmp_path, overrides, first, second, folder):
    conf = tmp_path / "conf" / "model"
    conf.mkdir(parents=True)
    (conf / "idle_again.yaml").write_text("name: idle\nagent: idle\nharness: direct\n")  # another option, same name
    sweep = tmp_path / "sw"
    r = cab_m(sweep, "sim=pybullet", *overrides, f"hydra.searchpath=[file://{tmp_path / 'conf'}]", timeout=120)
    assert r.returncode == 2, r.stderr[-3000:]
    assert r.stderr.strip().splitlines() == [
        f"cab: refused: jobs [{first}] and [{second}] would both write {folder}; nothing ran. Sweep over values "
        "that name different attempts (a seed given twice, e.g. seed=null and the task's own seed, or two "
        "options with the same name, are the same attempt)"]
    assert not sweep.exists()


def test_sweep_directory_of_the_first_layout_is_refused(tmp_path):
    sweep = tmp_path / "sw"
    old = sweep / "click_bell" / "idle" / "seed-0" / "attempt-1"
    old.mkdir(parents=True)
    manifest = {"manifest_version": "cab-sweep/1", "fingerprint": "sha256:0", "n_jobs": 2,
                "jobs": [["sim=mujoco"], ["sim=pybullet"]], "config": {}, "sessions": []}
    (sweep / MANIFEST).write_text(json.dumps(manifest))
    r = cab_m(sweep, "model=idle", "sim=pybullet,mujoco", timeout=120)
    assert r.returncode == 2, r.stderr[-3000:]
    assert r.stderr.strip().splitlines() == [
        f"cab: refused: {sweep} was written with the attempt layout <task>/<model>/seed-<S>/attempt-<A> "
        "(cab-sweep/1); this cab writes <task>/<model>/<sim>/[<swept>/]seed-<S>/attempt-<A> and would run every "
        "attempt again. Finish it with the cab version that started it, or start a new hydra.sweep.dir "
        "(cab-report reads both layouts)."]
    assert json.loads((sweep / MANIFEST).read_text()) == manifest
    assert sorted(str(p.relative_to(sweep)) for p in sweep.rglob("*")) == [
        "click_bell", "click_bell/idle", "click_bell/idle/seed-0", "click_bell/idle/seed-0/attempt-1", MANIFEST]


# -- the three simulators, end to end ---------------------------------------------------------------

@pytest.mark.sim
@pytest.mark.slow
def test_sweep_over_three_simulators_keeps_three_attempts(tmp_path):
    sweep = tmp_path / "sw"
    r = cab_m(sweep, "model=idle", "sim=sapien,pybullet,mujoco", timeout=900)
    assert r.returncode == 0, r.stderr[-3000:]
    sims = ("mujoco", "pybullet", "sapien")
    assert result_dirs(sweep) == [f"click_bell/idle/{s}/seed-0/attempt-1" for s in sims]
    for s in sims:
        res = json.loads((sweep / f"click_bell/idle/{s}/seed-0/attempt-1/result.json").read_text())
        assert (res["task"], res["model"], res["sim"], res["attempt"]) == ("click_bell", "idle", s, 1)
        assert not (sweep / f"click_bell/idle/{s}/seed-0/attempt-1/set_aside").exists()
    assert r.stderr.splitlines()[-1] == f"cab sweep: 3/3 attempts complete; {sweep}"
    rep = subprocess.run([os.path.join(BIN, "cab-report"), str(sweep), "--no-views"], capture_output=True,
                         text=True, timeout=300)
    assert rep.returncode == 0, rep.stderr[-3000:]
    report = json.loads((sweep / "report.json").read_text())
    assert report["attempts"] == 3 and report["in_flight"] == [] and report["problems"] == []
    assert {c["config"]: c["attempts"] for c in report["configs"]} == {f"idle (direct, {s})": 1 for s in sims}
    assert report["sweep"]["jobs"] == 3 and report["sweep"]["not_started"] == 0
    rows = [line for line in rep.stdout.splitlines() if line.startswith("| idle (direct, ")]
    assert sorted(line.split(" | ")[0] for line in rows) == [f"| idle (direct, {s})" for s in sims]
