"""Helpers shared by the CodeActionBench suite's task tests (tests/test_suite_*.py).

* :data:`TASKS` -- the suite's tasks as the plugin registry serves them, :data:`SEEDS` -- the seeds
  the layout and verifier checks sweep, :class:`Builds` -- their instances, built once a session
  (the ``task_builds`` fixture of conftest.py);
* :func:`_cache` -- an autouse fixture (import it into a test module) that sends generated assets to a
  per-session temp cache, never ~/.cache or the source tree;
* :class:`FakeWorld` -- a WorldView-compatible stand-in served from plain data (no simulator), and
  :func:`fake_world`, which picks the stand-in a task needs (:class:`LaptopWorld` serves link poses);
* ``check_*`` -- the contract checks every task passes (tests/test_suite_tasks.py runs them on every
  task: deterministic JSON builds, distinct seeded layouts, docstring sections, a verifier that
  rejects the initial scene, catalog-matching checkpoint declarations);
* :func:`sapien_world`, :func:`check_settled_scene_fails`, :func:`check_success_holds`,
  :func:`assert_settles`, :func:`world_view` -- the SAPIEN scaffolding of the groups' ``sim`` tests.
"""
from __future__ import annotations

import importlib
import json
import os
import xml.etree.ElementTree as ET
from contextlib import contextmanager

import numpy as np
import pytest

from cab_core.contracts.checkpoints import SpatialRule
from cab_core.contracts.verifier import WorldView
from cab_core.geometry import mat_to_quat, pose_mul
from cab_core.plugins import all_tasks, create
from cab_core.testing.task_conformance import margins_agree
from cab_suite_codeaction.assets_articulated import lid_rotation

# the embodiment's home TCP poses
HOME_TCP = {"left": [-0.300, -0.194, 0.942, 0.7071068, 0.0, 0.0, 0.7071068],
            "right": [0.305, -0.193, 0.941, 0.7071068, 0.0, 0.0, 0.7071068]}
ARM_OF = {"L": "left", "R": "right", "Either": "either"}
DOC_SECTIONS = ("Description", "Randomisation", "Success")
SEEDS = range(20)
# the CodeActionBench suite's tasks, from the plugin registry (every test_suite_*.py group is a part)
TASKS = {n: t for n, t in all_tasks().items() if type(t).__module__.startswith("cab_suite_codeaction.")}


def task_module(name):
    """The module that defines task ``name`` (its docstring, its helpers)."""
    return importlib.import_module(type(TASKS[name]).__module__)


def cache_dir(tmp_path_factory):
    return str(tmp_path_factory.getbasetemp() / "cab-cache")


@pytest.fixture(autouse=True)
def _cache(tmp_path_factory, monkeypatch):
    # generated assets go to a per-session temp cache, never ~/.cache or the source tree
    monkeypatch.setenv("CAB_CACHE_DIR", cache_dir(tmp_path_factory))


class Builds:
    """``builds[name]``: task ``name``'s instances at :data:`SEEDS` (no embodiment), built on first use
    with generated assets in the session's cache, then kept. Shared: read them, never change them
    (a test that edits an instance builds its own)."""

    def __init__(self, cache: str):
        self._cache, self._built = cache, {}

    def __getitem__(self, name):
        if name not in self._built:
            old = os.environ.get("CAB_CACHE_DIR")
            os.environ["CAB_CACHE_DIR"] = self._cache
            try:
                self._built[name] = [TASKS[name].build(s, None) for s in SEEDS]
            finally:
                if old is None:
                    os.environ.pop("CAB_CACHE_DIR", None)
                else:
                    os.environ["CAB_CACHE_DIR"] = old
        return self._built[name]


class FakeWorld:
    """WorldView-compatible stand-in: pose, qpos, link_pose, tcp_pose, gripper_command, in_contact,
    gripper_touches, contacts and info, served from plain data.

    Tests edit ``poses``, ``qpositions``, ``tcp``, ``grip``, ``touching`` (frozenset pairs in
    contact), ``finger_touch`` ((arm, object) pairs a gripper touches) and ``contact_list``
    (:class:`cab_core.contracts.simulator.Contact` records, which also count as pairs in contact).
    """

    def __init__(self, instance, grip: float = 1.0):
        self.info = instance.info
        self.poses = {b.name: np.array(b.pose, dtype=float) for b in instance.scene.bodies}
        self.qpositions = {}
        for a in instance.scene.articulations:
            self.poses[a.name] = np.array(a.pose, dtype=float)
            self.qpositions[a.name] = np.array(a.qpos or (), dtype=float)
        self.tcp = {a: np.array(p, dtype=float) for a, p in HOME_TCP.items()}
        self.grip = {"left": grip, "right": grip}
        self.touching: set[frozenset[str]] = set()
        self.finger_touch: set[tuple[str, str]] = set()
        self.contact_list: list = []

    def pose(self, name):
        return self.poses[name].copy()

    def qpos(self, name):
        return self.qpositions.get(name, np.zeros(0)).copy()

    def link_pose(self, name, link):
        raise NotImplementedError

    def tcp_pose(self, arm):
        return self.tcp[arm].copy()

    def gripper_command(self, arm):
        return float(self.grip[arm])

    def in_contact(self, a, b, min_impulse=0.0):
        return frozenset((a, b)) in self.touching or any({c.a, c.b} == {a, b} for c in self.contact_list)

    def gripper_touches(self, arm, obj):
        return (arm, obj) in self.finger_touch

    def contacts(self):
        return list(self.contact_list)


class LaptopWorld(FakeWorld):
    """The stand-in of open_laptop_setup_arm: also the laptop's lid link pose (from the URDF's hinge
    frame)."""

    def link_pose(self, name, link):
        lap = self.info["laptop"]
        assert name == lap["name"]
        root = self.poses[name]
        if link == lap["base_link"]:
            return root.copy()
        assert link == lap["lid_link"]
        q = float(self.qpositions[name][lap["lid_joint_index"]])
        local = np.concatenate([lap["hinge_point_base"], mat_to_quat(lid_rotation(q))])
        return pose_mul(root, local)


def task_and_verifier(name, seed=0):
    """Task ``name``, a fresh build of it at ``seed`` (no embodiment) and that instance's verifier."""
    task = TASKS[name]
    inst = task.build(seed, None)
    return task, inst, task.verifier(inst)


def tcp_in_rule(rule, w, arm):
    """Whether ``arm``'s TCP in world ``w`` is inside spatial ``rule``'s target (offsets in cm)."""
    return rule.test((w.tcp_pose(arm)[:3] - np.asarray(rule.reference(w))) * 100)


def fake_world(name, inst, **kw):
    """The stand-in world task ``name``'s verifier reads."""
    return (LaptopWorld if name == "open_laptop_setup_arm" else FakeWorld)(inst, **kw)


# --- contract checks ------------------------------------------------------------------------------
def check_doc_sections(doc):
    for section in DOC_SECTIONS:
        assert section in doc


def check_build_is_deterministic_and_json(task, seeds=(0, 7), required=("table", "wall")):
    for seed in seeds:
        a, b = task.build(seed, None), task.build(seed, None)
        assert a.scene == b.scene
        assert json.dumps(a.info, sort_keys=True) == json.dumps(b.info, sort_keys=True)
        json.loads(json.dumps(a.info))  # serialisable
        names = a.scene.names()
        assert len(names) == len(set(names)) and set(required) <= set(names)


def layout_of(scene):
    """Every body's and articulation's pose, rounded: one seeded layout."""
    return tuple(np.round(np.concatenate([b.pose for b in scene.bodies] + [a.pose for a in scene.articulations]), 6))


def check_seeds_give_different_layouts(instances):
    assert len({layout_of(inst.scene) for inst in instances}) == len(instances)


def check_verifier_false_on_the_initial_scene(task, instances, world=FakeWorld):
    """Each instance fails, with boolean predicates whose margins agree, and guards bodies of its scene only."""
    for inst in instances:
        v = task.verifier(inst)
        ev = v.evaluate(world(inst))
        assert ev.success is False
        assert ev.predicates and all(isinstance(x, bool) for x in ev.predicates.values())
        check_margins_agree(ev.predicates, {k: m.as_record() for k, m in ev.margins.items()})
        assert set(v.guarded_objects) <= {b.name for b in inst.scene.bodies}


check_margins_agree = margins_agree  # the conformance suite's check


def catalog_prerequisites(text):
    """A catalog prerequisite as rule indices: '--' (or none) is (), '1,3' is (0, 2); None for prose."""
    if text in ("--", None):
        return ()
    parts = str(text).split(",")
    return tuple(int(p) - 1 for p in parts) if all(p.strip().isdigit() for p in parts) else None


def check_rules_match_catalog(rules, spec):
    """Spatial rules: one per catalog checkpoint, same name and arm, prerequisites earlier rules only,
    those the catalog names where it names them by number."""
    assert len(rules) == len(spec)
    for i, (r, c) in enumerate(zip(rules, spec)):
        assert isinstance(r, SpatialRule) and r.name == c["name"] and r.arm == ARM_OF[c["arm"]]
        assert all(0 <= p < i for p in r.prerequisites)
        want = catalog_prerequisites(c["prerequisite"])
        assert want is None or r.prerequisites == want, (r.name, c["prerequisite"])


def check_urdf_hinge(urdf, links, joint, limits, origin, axis=None):
    """The URDF file ``urdf`` has exactly ``links`` and one revolute joint, ``joint``, with ``limits``
    (lower, upper), its origin at ``origin`` and (where given) its axis along ``axis``."""
    root = ET.parse(urdf).getroot()
    assert {link.get("name") for link in root.iter("link")} == set(links)
    (j,) = root.iter("joint")
    assert j.get("name") == joint and j.get("type") == "revolute"
    lim = j.find("limit")
    assert (float(lim.get("lower")), float(lim.get("upper"))) == tuple(limits)
    assert np.allclose([float(v) for v in j.find("origin").get("xyz").split()], origin)
    if axis is not None:
        assert np.allclose([float(v) for v in j.find("axis").get("xyz").split()], axis)


# --- with the SAPIEN backend ------------------------------------------------------------------------
def sapien_backend(sim_config=None):
    """The SAPIEN simulator and the aloha_agilex embodiment, or skip the test."""
    try:
        sim = create("simulators", "sapien", {"render": False} if sim_config is None else sim_config)
        emb = create("embodiments", "aloha_agilex", {})
    except Exception as e:  # backend or embodiment not installed / not ready
        pytest.skip(f"SAPIEN backend or embodiment unavailable: {e}")
    return sim, emb


def assert_settles(sim, inst, steps, tol=1e-3):
    """The dynamic bodies move less than ``tol`` over ``steps`` more steps; returns their poses
    before those steps."""
    dyn = [b.name for b in inst.scene.bodies if b.kind == "dynamic"]
    before = {n: sim.get_object_pose(n) for n in dyn}
    sim.step(steps)
    for n in dyn:
        assert np.linalg.norm(sim.get_object_pose(n)[:3] - before[n][:3]) < tol, n
    return before


def world_view(sim, emb, inst, grips=None):
    return WorldView(sim, emb, {a: 1.0 for a in emb.arms} if grips is None else grips, inst.info)


@contextmanager
def sapien_world(task, seed=None, sim_config=None, edit=None):
    """``task``'s instance (at its catalog seed unless ``seed``; ``edit(inst)`` may add to it) built in
    :func:`sapien_backend`: yields ``(sim, emb, inst)``, and closes the simulator after."""
    sim, emb = sapien_backend(sim_config)
    inst = task.build(task.info.seed if seed is None else seed, emb)
    if edit is not None:
        edit(inst)
    try:
        sim.build(inst.scene, emb)
        yield sim, emb, inst
    finally:
        sim.close()


def check_settled_scene_fails(task, sim, emb, inst, steps, tol=1e-3, grips=None):
    """After the task's settle steps the dynamic bodies stay within ``tol`` over ``steps`` more, and
    the verifier rejects the scene: no success, every guard holds, no subgoal attained. Returns the
    world view, the verifier and the poses :func:`assert_settles` started from."""
    sim.step(task.settle_steps())
    before = assert_settles(sim, inst, steps, tol)
    w = world_view(sim, emb, inst, grips)
    v = task.verifier(inst)
    assert v.evaluate(w).success is False
    assert all(v.guard(w).values())
    assert task.subgoals(w) == [False] * len(task.info.subgoals)
    return w, v, before


def check_success_holds(task, sim, w, v, steps):
    """``steps`` steps on, the verifier accepts the world and every subgoal is attained."""
    sim.step(steps)
    ev = v.evaluate(w)
    assert ev.success, ev
    assert all(task.subgoals(w))
    return ev
