"""The contract every task of the CodeActionBench suite keeps, checked on each task the plugin
registry serves (suite_helpers.TASKS): its info is the catalog entry, its module documents it, its
scoring and guards are as declared, seeded builds are deterministic, JSON and distinct, the verifier
rejects every initial layout, and its subgoals and spatial checkpoints match the catalog.

What is particular to a task or a group (layouts, assets, hand-built success states, the ``sim``
tests) is in that group's tests/test_suite_<group>.py.
"""
from __future__ import annotations

import numpy as np
import pytest
from suite_helpers import (  # noqa: F401 (_cache: autouse)
    TASKS,
    _cache,
    check_build_is_deterministic_and_json,
    check_doc_sections,
    check_rules_match_catalog,
    check_seeds_give_different_layouts,
    check_verifier_false_on_the_initial_scene,
    fake_world,
    task_module,
)

from cab_core.contracts.task import Task
from cab_suite_codeaction import catalog
from cab_suite_codeaction.tasks import TASK_MODULES

NAMES = sorted(TASKS)
LATCH = {"beat_block_hammer", "click_bell", "press_stapler", "dump_bin_bigbin"}  # every other task: "final"
UNGUARDED = {"open_microwave", "open_laptop_setup_arm", "click_bell", "press_stapler"}  # nothing to knock over
TABLE_TOP = 0.74
GUARD_MIN_Z = {"place_dual_shoes": 0.64 - 0.08,  # the lowered table
               "put_bottles_dustbin": 0.1, "dump_bin_bigbin": 0.05}  # the dustbin stands on the floor
REQUIRED = {"open_laptop_setup_arm": ("laptop",), "place_dual_shoes": ("left_shoe", "right_shoe", "shoe_box")}
# a rule whose target region leaves its reference point out: stack_bowls_three's annulus round a rim
REFERENCE_OUTSIDE = {"stack_bowls_three"}


def test_every_task_module_is_served():
    """The cases below are all the catalog's tasks: the registry serves one per task module."""
    assert NAMES == sorted(TASK_MODULES) == sorted(catalog.task_names())


@pytest.mark.parametrize("name", NAMES)
def test_task_info_docstring_scoring_and_guards(name, task_builds):
    task = TASKS[name]  # (task_builds[name][s] is the build at seed s: suite_helpers.SEEDS is range(20))
    assert isinstance(task, Task) and task.name == name
    assert task.__class__.__module__.rsplit(".", 1)[1] == name
    assert task.info == catalog.task_info(name)
    check_doc_sections(task_module(name).__doc__)
    inst = task_builds[name][task.info.seed]
    v = task.verifier(inst)
    assert v.scoring == task.info.scoring == ("latch" if name in LATCH else "final")
    if v.scoring == "latch":
        assert v.poll_every == 1
    assert bool(v.guarded_objects) == (name not in UNGUARDED)
    assert all(o in inst.scene.names() for o in v.guarded_objects)
    if v.guarded_objects:
        assert v.guard_min_z == pytest.approx(GUARD_MIN_Z.get(name, TABLE_TOP - 0.08))


@pytest.mark.parametrize("name", NAMES)
def test_build_is_deterministic_and_json(name):
    task = TASKS[name]
    seeds = sorted({0, task.info.seed, 7})
    check_build_is_deterministic_and_json(task, seeds=seeds, required=("table", "wall", *REQUIRED.get(name, ())))


@pytest.mark.parametrize("name", NAMES)
def test_seeds_give_different_layouts(name, task_builds):
    check_seeds_give_different_layouts(task_builds[name])


@pytest.mark.parametrize("name", NAMES)
def test_verifier_false_on_the_initial_scene(name, task_builds):
    check_verifier_false_on_the_initial_scene(TASKS[name], task_builds[name], lambda inst: fake_world(name, inst))


@pytest.mark.parametrize("name", NAMES)
def test_checkpoint_declarations_match_the_catalog(name, task_builds):
    """At seed 0 and at the catalog seed: one boolean subgoal per catalog subgoal, none attained,
    one spatial rule per catalog checkpoint (name, arm, prerequisites), each reference a finite
    point that its own test accepts."""
    task = TASKS[name]
    entry = next(t for t in catalog.load_catalog()["tasks"] if t["name"] == name)
    for seed in sorted({0, task.info.seed}):
        inst = task_builds[name][seed]
        w = fake_world(name, inst)
        sg = task.subgoals(w)
        assert len(sg) == len(task.info.subgoals) == entry["subgoal_count"]
        assert all(isinstance(s, bool) for s in sg) and not any(sg)  # nothing attained at the start
        rules = task.spatial_checkpoints(inst.info)
        assert len(rules) == entry["spatial_count"]
        check_rules_match_catalog(rules, task.info.spatial_checkpoints)
        for r in rules:
            if r.lift_above_cm is None:
                ref = np.asarray(r.reference(w), float)
                assert ref.shape == (3,) and np.all(np.isfinite(ref))
                hit = r.test(np.zeros(3))
                assert hit in (True, False) and bool(hit) == (name not in REFERENCE_OUTSIDE)
