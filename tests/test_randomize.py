"""Appearance randomisation (cab_core.attempt.variation.randomize) and the report's tables beyond the
fixed instances (cab_core.analysis.instances)."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from hydra import compose, initialize_config_module
from PIL import Image

from cab_core.analysis import instances
from cab_core.apps.cli import normalise_overrides
from cab_core.attempt.runner import attempt_spec, run_attempt
from cab_core.attempt.variation.randomize import Randomization, names_a_colour, randomize_instance
from cab_core.errors import ConfigError
from cab_core.geometry import extrinsic_from_pose
from cab_core.plugins import all_tasks, create


def cfg(option: str) -> dict:
    with initialize_config_module(version_base=None, config_module="cab_core.conf"):
        from omegaconf import OmegaConf

        return OmegaConf.to_container(compose(config_name="config", overrides=[f"randomize={option}"]).randomize)


def run(out: Path, *overrides: str) -> dict:
    with initialize_config_module(version_base=None, config_module="cab_core.conf"):
        c = compose(config_name="config", overrides=normalise_overrides(["record.video=false", *overrides]))
    return run_attempt(attempt_spec(c, out))


def instance(task: str, seed: int = 0):
    emb = create("embodiments", "aloha_agilex", {"name": "aloha_agilex"})
    t = all_tasks()[task]
    return t, t.build(seed, emb), emb


def test_options_and_their_parameters_are_checked():
    assert Randomization.from_cfg(cfg("none")) is None
    r = Randomization.from_cfg(cfg("all"))
    assert r.name == "all" and set(r.parts) == {"lighting", "textures", "camera", "distractors"}
    assert set(Randomization.from_cfg(cfg("camera")).parts) == {"camera"}
    for bad, msg in [({"name": "x", "lighting": {"intensity": [1.4, 0.6]}}, "range"),
                     ({"name": "x", "camera": {"angle_deg": -1}}, "non-negative"),
                     ({"name": "x", "camera": {"tilt": 1}}, "unknown randomize.camera key"),
                     ({"name": "x", "weather": {}}, "unknown randomize key")]:
        with pytest.raises(ConfigError, match=msg):
            Randomization.from_cfg(bad)


def test_draws_follow_the_seed_and_each_part_has_its_own_stream():
    r_all, r_light = Randomization.from_cfg(cfg("all")), Randomization.from_cfg(cfg("lighting"))
    task, a, emb = instance("lift_pot")
    _, b, _ = instance("lift_pot")
    _, c, _ = instance("lift_pot", 1)
    slots = task.distractor_slots(a)
    ea, ra = randomize_instance(a.scene, emb, r_all, 0, "lift_pot", task.info.instruction, slots)
    _, rb = randomize_instance(b.scene, emb, r_all, 0, "lift_pot", task.info.instruction, slots)
    _, rc = randomize_instance(c.scene, emb, r_all, 1, "lift_pot", task.info.instruction, task.distractor_slots(c))
    assert ra == rb and ra["lighting"] != rc["lighting"]
    _, d, _ = instance("lift_pot")
    _, rd = randomize_instance(d.scene, emb, r_light, 0, "lift_pot", task.info.instruction, [])
    assert rd["lighting"] == ra["lighting"]  # the other parts drawn or not: the same light
    # the head camera is moved (and only it: the wrist cameras are the robot's)
    moved = {c.name: c.pose for c in ea.cameras}
    for cam in emb.cameras:
        assert (moved[cam.name] != cam.pose) == (cam.mount_link is None), cam.name
    assert 0 < ra["camera"]["head_camera"]["moved_m"] <= 0.01 and ra["camera"]["head_camera"]["turned_deg"] <= 1.5


def test_objects_keep_their_colours_when_the_instruction_names_one():
    named = [t for t, task in all_tasks().items() if names_a_colour(task.info.instruction)]
    assert names_a_colour("Put the red block on the Blue one.") == ["red", "blue"]
    r = Randomization.from_cfg(cfg("textures"))
    for t in named[:2] or ["lift_pot"]:
        task, inst, emb = instance(t)
        before = {b.name: [s.material.color for s in b.shapes] for b in inst.scene.bodies if b.kind != "static"}
        _, rec = randomize_instance(inst.scene, emb, r, 0, t, task.info.instruction, [])
        after = {b.name: [s.material.color for s in b.shapes] for b in inst.scene.bodies if b.kind != "static"}
        if named:
            assert after == before and "names a colour" in rec["textures"]["objects_kept"]
    task, inst, emb = instance("lift_pot")  # "Use both arms to lift the pot, keeping it level."
    pot = [s.material.color for s in next(b for b in inst.scene.bodies if b.name == "pot").shapes]
    randomize_instance(inst.scene, emb, r, 0, "lift_pot", task.info.instruction, [])
    assert [s.material.color for s in next(b for b in inst.scene.bodies if b.name == "pot").shapes] != pot


def test_distractors_stay_clear_of_every_task_object():
    r = Randomization.from_cfg({"name": "d", "distractors": {"count": [4, 4]}})
    offered = 0
    for name, task in all_tasks().items():
        _, inst, emb = instance(name)
        slots = task.distractor_slots(inst)
        offered += len(slots)
        others = [np.asarray(b.pose[:2]) for b in inst.scene.bodies if b.name not in ("table", "wall")]
        _, rec = randomize_instance(inst.scene, emb, r, 0, name, task.info.instruction, slots)
        placed = rec["distractors"]["placed"]
        assert len(placed) == len(slots)
        for d in placed:
            assert all(np.linalg.norm(np.asarray(d["xy"]) - o) > 0.12 for o in others), (name, d)
    assert offered >= 25  # most tasks offer at least one place


def test_a_randomised_attempt_looks_different_and_its_calibration_follows_the_camera(tmp_path):
    plain = run(tmp_path / "plain", "sim=mujoco", "task=click_bell")
    rnd = run(tmp_path / "all", "sim=mujoco", "task=click_bell", "randomize=all")
    assert plain["verdict"]["success"] and rnd["verdict"]["success"]
    assert "randomization" not in plain and rnd["randomization"]["name"] == "all"
    a = np.asarray(Image.open(tmp_path / "plain" / "observations" / "obs_0001.png"), float)
    b = np.asarray(Image.open(tmp_path / "all" / "observations" / "obs_0001.png"), float)
    assert np.abs(a - b).mean() > 10  # visibly different
    first = lambda d: next(json.loads(line) for line in (d / "events.jsonl").read_text().splitlines()  # noqa: E731
                           if '"capture_head"' in line and '"kind": "call"' in line)
    E = np.asarray(first(tmp_path / "all")["result"]["cam_pose_snapshot"]["E"], float)
    pose = rnd["randomization"]["camera"]["head_camera"]["pose"]
    assert np.allclose(E, extrinsic_from_pose(np.asarray(pose))[:3], atol=2e-5)
    assert not np.allclose(E, np.asarray(first(tmp_path / "plain")["result"]["cam_pose_snapshot"]["E"], float), atol=1e-4)


def test_the_report_sets_held_out_and_randomised_success_beside_the_catalog():
    rows = [{"config": "o", "task": "click_bell", "seed": s, "success": ok, "randomize": rz}
            for s, ok, rz in [(0, True, "none"), (100, True, "none"), (101, False, "all"), (7, True, "all")]]
    kinds = instances.seed_kinds({"click_bell"})
    assert kinds["click_bell"][0] == "catalog" and kinds["click_bell"][100] == "heldout"
    inst = instances.by_instance_kind(rows, kinds)
    assert {k: (c["successes"], c["attempts"]) if c else None for k, c in inst["o"].items()} == {
        "catalog": (1, 1), "heldout": (1, 2), "other": (1, 1)}
    lo, hi = inst["o"]["heldout"]["wilson95"]
    assert (round(lo, 4), round(hi, 4)) == (0.0945, 0.9055)  # Wilson, 1 of 2
    rnd = instances.by_randomization(rows)
    assert rnd["options"] == ["none", "all"]
    assert (rnd["configs"]["o"]["all"]["successes"], rnd["configs"]["o"]["all"]["attempts"]) == (1, 2)
    only_catalog = [dict(r, seed=0, randomize="none") for r in rows]
    assert instances.by_instance_kind(only_catalog, kinds) is None and instances.by_randomization(only_catalog) is None
