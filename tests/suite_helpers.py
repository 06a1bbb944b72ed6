"""Helpers shared by the CodeActionBench suite's task tests (tests/test_suite_*.py).

* :func:`_cache` -- an autouse fixture (import it into a test module) that sends generated assets to a
  per-session temp cache, never ~/.cache or the source tree;
* :class:`FakeWorld` -- a WorldView-compatible stand-in served from plain data (no simulator);
* ``check_*`` -- the contract checks every task group repeats (deterministic JSON builds, distinct
  seeded layouts, docstring sections, a verifier that rejects the initial scene, catalog-matching
  checkpoint declarations);
* :func:`sapien_backend`, :func:`assert_settles`, :func:`world_view` -- the SAPIEN scaffolding of the
  ``sim`` tests.
"""
from __future__ import annotations

import json

import numpy as np
import pytest

from cab_core.contracts.checkpoints import SpatialRule
from cab_core.testing.task_conformance import margins_agree

# the embodiment's home TCP poses
HOME_TCP = {"left": [-0.300, -0.194, 0.942, 0.7071068, 0.0, 0.0, 0.7071068],
            "right": [0.305, -0.193, 0.941, 0.7071068, 0.0, 0.0, 0.7071068]}
ARM_OF = {"L": "left", "R": "right", "Either": "either"}
DOC_SECTIONS = ("Description", "Randomisation", "Success")


@pytest.fixture(autouse=True)
def _cache(tmp_path_factory, monkeypatch):
    # generated assets go to a per-session temp cache, never ~/.cache or the source tree
    monkeypatch.setenv("CAB_CACHE_DIR", str(tmp_path_factory.getbasetemp() / "cab-cache"))


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


def layout_of(scene, articulations=False):
    poses = [b.pose for b in scene.bodies] + ([a.pose for a in scene.articulations] if articulations else [])
    return tuple(np.round(np.concatenate(poses), 6))


def check_seeds_give_different_layouts(task, seeds, articulations=False):
    assert len({layout_of(task.build(s, None).scene, articulations) for s in seeds}) == len(seeds)


def check_verifier_false_on_the_initial_scene(task, seeds, world=FakeWorld):
    for seed in seeds:
        inst = task.build(seed, None)
        ev = task.verifier(inst).evaluate(world(inst))
        assert ev.success is False
        assert ev.predicates and all(isinstance(v, bool) for v in ev.predicates.values())
        check_margins_agree(ev.predicates, {k: m.as_record() for k, m in ev.margins.items()})


check_margins_agree = margins_agree  # the conformance suite's check


def check_rules_match_catalog(rules, spec):
    """Spatial rules: one per catalog checkpoint, same name and arm, prerequisites in range."""
    assert len(rules) == len(spec)
    for r, c in zip(rules, spec):
        assert isinstance(r, SpatialRule) and r.name == c["name"] and r.arm == ARM_OF[c["arm"]]
        assert all(0 <= p < len(rules) for p in r.prerequisites)


# --- with the SAPIEN backend ------------------------------------------------------------------------
def sapien_backend(sim_config=None):
    """The SAPIEN simulator and the aloha_agilex embodiment, or skip the test."""
    from cab_core.plugins import create

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
    from cab_core.contracts.verifier import WorldView

    return WorldView(sim, emb, {a: 1.0 for a in emb.arms} if grips is None else grips, inst.info)
