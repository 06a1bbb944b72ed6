"""Checkpoint evaluation from records, on synthetic snapshots (no simulator)."""
from types import SimpleNamespace

import numpy as np
import pytest

from cab_core.attempt.engine.checkpoint_scoring import evaluate
from cab_core.contracts.checkpoints import SpatialRule, annulus, box, cylinder, sphere
from cab_core.contracts.embodiment import ArmSpec, EmbodimentSpec, GripperSpec


def emb():
    g = GripperSpec(("j7", "j8"), ("f7", "f8"), -0.01, 0.045, 0.048)

    def arm(n):
        return ArmSpec(n, ("j1",), "b", "ee", f"{n}_tcp", "cam", g, (0.0,))

    return EmbodimentSpec("fake", "", "", (0, 0, 0, 1, 0, 0, 0), {"left": arm("left"), "right": arm("right")}, ())


def snap(label, cube_xyz, left_tcp, right_tcp=(0.3, -0.2, 0.9), calls=0):
    return {"label": label, "calls": calls, "physics_step": calls * 100,
            "objects": {"cube": {"pose": list(cube_xyz) + [1, 0, 0, 0]}},
            "arms": {"left": {"tcp_pose": list(left_tcp) + [1, 0, 0, 0], "gripper_cmd": 1.0},
                     "right": {"tcp_pose": list(right_tcp) + [1, 0, 0, 0], "gripper_cmd": 1.0}},
            "contacts": []}


class FakeTask:
    info = SimpleNamespace(subgoals=("cube raised",))

    def subgoals(self, w):
        return [w.pose("cube")[2] > 0.80]

    def spatial_checkpoints(self, info):
        def cube(w):
            return w.pose("cube")[:3]

        return [SpatialRule("approach", "either", cube, sphere(2)),
                SpatialRule("lift", "left", None, None, prerequisites=(0,), lift_above_cm=5),
                SpatialRule("right only", "right", cube, sphere(2))]


def test_first_match_prerequisites_and_relative_lift():
    snaps = [snap("start", (0, 0, 0.76), (-0.3, -0.2, 0.9)),
             snap("a", (0, 0, 0.76), (0.0, 0.0, 0.775), calls=1),   # approach matched (1.5 cm)
             snap("b", (0, 0, 0.78), (0.0, 0.0, 0.80), calls=2),    # lifted 2.5 cm: not yet
             snap("c", (0, 0, 0.83), (0.0, 0.0, 0.85), calls=3),    # lifted 7.5 cm: lift matched, subgoal
             snap("d", (0, 0, 0.76), (0.0, 0.0, 0.775), calls=4)]   # regression keeps earlier matches
    rep = evaluate(FakeTask(), emb(), {}, snaps)
    assert [s["attained"] for s in rep.spatial] == [True, True, False]
    assert rep.spatial[0]["first"]["calls"] == 1 and rep.spatial[0]["first"]["arm"] == "left"
    assert rep.spatial[1]["first"]["calls"] == 3
    assert rep.subgoals[0]["attained"] and rep.subgoals[0]["first"]["calls"] == 3
    assert rep.spatial_coverage == pytest.approx(2 / 3) and rep.subgoal_coverage == 1.0


def test_prerequisite_must_come_first():
    # the TCP is lifted before any approach: the lift cannot match
    snaps = [snap("start", (0, 0, 0.76), (-0.3, -0.2, 0.9)), snap("a", (0, 0, 0.76), (0.0, 0.0, 1.0), calls=1)]
    rep = evaluate(FakeTask(), emb(), {}, snaps)
    assert [s["attained"] for s in rep.spatial] == [False, False, False]


def test_subgoal_true_at_start_is_not_credited_until_it_was_false():
    snaps = [snap("start", (0, 0, 0.9), (-0.3, -0.2, 0.9)), snap("a", (0, 0, 0.9), (-0.3, -0.2, 0.9), calls=1),
             snap("b", (0, 0, 0.76), (-0.3, -0.2, 0.9), calls=2), snap("c", (0, 0, 0.9), (-0.3, -0.2, 0.9), calls=3)]
    rep = evaluate(FakeTask(), emb(), {}, snaps)
    assert rep.subgoals[0]["first"]["calls"] == 3


def test_latch_credits_declared_subgoals():
    snaps = [snap("start", (0, 0, 0.76), (-0.3, -0.2, 0.9))]
    rep = evaluate(FakeTask(), emb(), {"latch_subgoals": [0]}, snaps, latched=True)
    assert rep.subgoals[0]["attained"] and rep.subgoals[0]["first"]["label"] == "latch event"


@pytest.mark.parametrize("test,delta,expect", [
    (box(dx=2, dy=6, dz=(-3, 4)), (1.9, -5.9, 3.9), True),
    (box(dx=2, dy=6, dz=(-3, 4)), (0, 0, -3.1), False),
    (cylinder(2, (-6, 2)), (1.2, 1.5, -5), True),
    (cylinder(2, (-6, 2)), (1.5, 1.5, 0), False),
    (sphere(5), (3, 3, 2), True),
    (sphere(5), (3, 3, 3), False),
    (annulus(6, 2, 5), (0, 7.5, 0), True),
    (annulus(6, 2, 5), (0, 3.5, 0), False),
])
def test_region_shapes(test, delta, expect):
    assert test(np.asarray(delta, float)) is expect


def test_any_of_prerequisites():
    rule = SpatialRule("place", "either", lambda w: (0, 0, 0), sphere(2), prerequisites=(0, 1), any_prerequisite=True)
    assert rule.ready([None, {"calls": 1}]) and not rule.ready([None, None])
    strict = SpatialRule("place", "either", lambda w: (0, 0, 0), sphere(2), prerequisites=(0, 1))
    assert not strict.ready([None, {"calls": 1}]) and strict.ready([{"calls": 1}, {"calls": 2}])
