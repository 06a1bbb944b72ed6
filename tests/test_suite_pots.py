"""The kitchen tasks of the CodeActionBench suite (lift_pot, grab_roller_dual_contact, move_can_pot):
seeded layouts within the FACTS ranges, verifiers that accept hand-built success states and reject
near misses, and spatial references that follow the objects.

Verifiers run on :class:`FakeWorld` (plain data, no simulator); the ``sim`` tests build the real
scene with the SAPIEN backend (physics only) and check that it settles and fails the verifier.

The contract every task keeps (catalog entry, deterministic JSON builds, distinct seeded layouts, a
verifier that rejects every initial layout, catalog checkpoints) is checked in test_suite_tasks.py.
"""
from __future__ import annotations

import numpy as np
import pytest
import suite_helpers as sh
from suite_helpers import TASKS, FakeWorld, _cache, task_and_verifier, tcp_in_rule  # noqa: F401 (_cache: autouse)

from cab_core.geometry import axis_angle_quat, quat_mul, quat_to_mat, transform_point
from cab_core.kits.scene import lowest_point_z, yaw_of

NAMES = ("lift_pot", "grab_roller_dual_contact", "move_can_pot")


def _yaw(q):
    return yaw_of(q)


def _lowest_z(body):
    """The height of the body's lowest point (0.74 is the table top)."""
    return body.pose[2] + lowest_point_z(body.shapes, body.pose[3:])


# --- lift_pot ----------------------------------------------------------------------------------------
def test_lift_pot_layouts(task_builds):
    models = set()
    for inst in task_builds["lift_pot"]:
        pot = inst.scene.body("pot")
        x, y = pot.pose[:2]
        assert -0.05 <= x <= 0.05 and -0.05 <= y <= 0.05
        assert abs(_yaw(pot.pose[3:])) <= np.pi / 8 + 1e-9
        assert np.allclose(quat_to_mat(pot.pose[3:])[:, 2], (0, 0, 1))
        assert 0.74 <= _lowest_z(pot) <= 0.7405
        assert pot.kind == "dynamic" and 0.5 <= pot.mass <= 1.5
        p = inst.info["pot"]
        models.add(p["model_id"])
        h0, h1 = (np.asarray(h) for h in p["handle_points"])
        assert h0[0] < -p["radius"] < p["radius"] < h1[0]  # handle 0 on -x (left arm), 1 on +x
        assert 0.5 * p["height"] < h0[2] < p["height"]
        assert p["handle_size"][1] < 0.08  # fits the open gripper
    assert models == {0, 1}


def _lifted(inst, w, dz=0.10, tilt=0.0, tcp_off=(0.0, 0.0, 0.0)):
    p = inst.info["pot"]
    pose = np.array(p["initial_pose"], float)
    pose[2] += dz
    pose[3:] = quat_mul(axis_angle_quat([1, 0, 0], tilt), pose[3:])
    w.poses["pot"] = pose
    for arm, h in zip(("left", "right"), p["handle_points"]):
        w.tcp[arm][:3] = transform_point(pose, h) + np.asarray(tcp_off)


def test_lift_pot_verifier():
    task, inst, v = task_and_verifier("lift_pot")
    assert v.guarded_objects == ("pot",)
    w = FakeWorld(inst, grip=0.0)
    _lifted(inst, w)
    ev = v.evaluate(w)
    assert ev.success and all(ev.predicates.values())
    assert task.subgoals(w) == [True, True, True, True]
    _lifted(inst, w, tcp_off=(0.0, 0.02, -0.02))  # 2.8 cm from each handle
    assert v.evaluate(w).success
    _lifted(inst, w, tcp_off=(0.0, 0.0, 0.031))
    ev = v.evaluate(w)
    assert not ev.success and not ev.predicates["left_at_handle"] and not ev.predicates["right_at_handle"]
    _lifted(inst, w, dz=0.82 - 0.7402 - 0.001)  # just below 0.82
    assert v.evaluate(w).predicates["pot_raised"] is False
    assert task.subgoals(w) == [True, True, False, False]
    _lifted(inst, w, tilt=0.7)  # cos(0.7) = 0.76 < 0.8: not level
    ev = v.evaluate(w)
    assert ev.predicates["pot_upright"] is False and not ev.success
    _lifted(inst, w, tilt=0.6)
    assert v.evaluate(w).success
    w.poses["pot"][2] = 0.6
    assert v.guard(w) == {"pot_on_table": False}


def test_lift_pot_spatial_references_follow_the_pot():
    task = TASKS["lift_pot"]
    inst = task.build(0, None)
    rules = task.spatial_checkpoints(inst.info)
    w = FakeWorld(inst)
    _lifted(inst, w, dz=0.0)
    for r in rules[:2]:
        arm = r.arm
        assert tcp_in_rule(r, w, arm)
        w2 = FakeWorld(inst)
        _lifted(inst, w2, dz=0.0, tcp_off=(0.021, 0.0, 0.0))
        assert not tcp_in_rule(r, w2, arm)
    # the lift needed: from the initial height (0.74) to 0.82
    assert rules[2].lift_above_cm == pytest.approx(100 * (0.82 - inst.info["pot"]["initial_z"]))


# --- grab_roller_dual_contact -----------------------------------------------------------------------
def test_grab_roller_layouts(task_builds):
    models = set()
    for inst in task_builds["grab_roller_dual_contact"]:
        roller = inst.scene.body("roller")
        x, y = roller.pose[:2]
        assert -0.15 <= x <= 0.15 and -0.25 <= y <= -0.05
        assert abs(_yaw(roller.pose[3:])) <= 0.8 + 1e-9
        assert abs(quat_to_mat(roller.pose[3:])[2, 0]) < 1e-9  # the axis lies flat
        assert 0.74 <= _lowest_z(roller) <= 0.7405
        r = inst.info["roller"]
        models.add(r["model_id"])
        h0, h1 = (transform_point(roller.pose, h) for h in r["handle_points"])
        assert h0[0] < x < h1[0]  # handle 0 on the left arm's side
        assert h0[2] - r["handle_radius"] > 0.745  # the handles are clear of the table
        assert 2 * r["handle_radius"] < 0.04 and 0.3 <= r["length"] <= 0.45
        assert 0.2 <= r["mass_kg"] <= 0.6
    assert models == {0, 2}


def test_grab_roller_verifier():
    task, inst, v = task_and_verifier("grab_roller_dual_contact")
    assert v.guarded_objects == ("roller",)
    w = FakeWorld(inst, grip=0.0)
    w.poses["roller"][2] = 0.85
    w.finger_touch |= {("left", "roller"), ("right", "roller")}
    ev = v.evaluate(w)
    assert ev.success and all(ev.predicates.values())
    assert task.subgoals(w) == [True, True, True, True]
    w.grip["right"] = 0.2  # must be strictly below 0.2
    ev = v.evaluate(w)
    assert not ev.success and ev.predicates["right_closed"] is False
    w.grip["right"] = 0.0
    w.finger_touch.discard(("left", "roller"))
    assert not v.evaluate(w).success and task.subgoals(w) == [False, True, True, False]
    w.finger_touch.add(("left", "roller"))
    w.poses["roller"][2] = 0.80
    assert v.evaluate(w).predicates["roller_raised"] is False
    assert task.subgoals(w) == [True, True, False, False]
    # lift needed by the relative lift checkpoints: from the resting axis height to 0.80
    rules = task.spatial_checkpoints(inst.info)
    assert rules[3].lift_above_cm == pytest.approx(100 * (0.80 - inst.info["roller"]["initial_z"]))


# --- move_can_pot ------------------------------------------------------------------------------------
def _upright(yaw):
    """The can standing (axis local +y -> world +z), turned by ``yaw`` about its axis."""
    return quat_mul(axis_angle_quat([0, 0, 1], yaw), [np.sqrt(0.5), np.sqrt(0.5), 0, 0])


def test_move_can_pot_layouts(task_builds):
    from cab_suite_codeaction.tasks.move_can_pot import euler_sxyz

    task = TASKS["move_can_pot"]
    pots, cans, arms = set(), set(), set()
    for inst in task_builds[task.name]:
        pot, can = inst.scene.body("pot"), inst.scene.body("can")
        assert np.allclose(pot.pose[:2], (0.0, 0.0)) and abs(_yaw(pot.pose[3:])) <= np.pi / 8 + 1e-9
        x, y, z = can.pose[:3]
        assert -0.3 <= x <= 0.3 and abs(x) >= 0.2 and 0.05 <= y <= 0.15
        assert np.hypot(x - pot.pose[0], y - pot.pose[1]) >= 0.3
        ax, ay, az = euler_sxyz(can.pose[3:])
        assert ax == pytest.approx(np.pi / 2) and ay == pytest.approx(0.0, abs=1e-9)
        assert abs(quat_to_mat(can.pose[3:])[2, 1] - 1.0) < 1e-9  # axis (local +y) straight up
        for body in (pot, can):
            assert 0.74 <= _lowest_z(body) <= 0.7405, body.name
        info = inst.info
        assert info["arm"] == ("left" if x < 0 else "right")
        c = info["can"]
        assert 2 * c["radius"] < 0.075 and 0.08 <= c["height"] <= 0.12
        p = info["pot"]
        # a can fits beside the pot within 0.2 m of its centre, past a handle tab turned toward it
        assert p["span_with_handles"] / 2 + c["radius"] + 0.01 < info["place_dis"] < info["max_dis"]
        pots.add(p["model_id"])
        cans.add(c["model_id"])
        arms.add(info["arm"])
    assert arms == {"left", "right"} and len(pots) >= 3 and len(cans) >= 4


def _placed(inst, w, dis=None, dy=0.0, tilt=0.0, dz=0.0, yaw=0.4):
    """The can upright (turned by ``yaw``), ``dis`` beside the pot on its side, tilted about world y
    by ``tilt`` (with yaw 0 that is the transforms3d Euler y angle alone)."""
    info = inst.info
    sign = -1.0 if info["arm"] == "left" else 1.0
    pot = np.asarray(info["pot"]["initial_pose"])
    d = info["place_dis"] if dis is None else dis
    q = quat_mul(axis_angle_quat([0, 1, 0], tilt), _upright(yaw))
    w.poses["can"] = np.array([pot[0] + sign * d, pot[1] - dy, info["pot"]["initial_z"] + dz, *q])


@pytest.mark.parametrize("seed", [0, 1])  # a left and a right instance
def test_move_can_pot_verifier(seed):
    task, inst, v = task_and_verifier("move_can_pot", seed)
    assert set(v.guarded_objects) == {"can", "pot"}
    w = FakeWorld(inst)
    _placed(inst, w)
    ev = v.evaluate(w)
    assert ev.success and all(ev.predicates.values()), ev
    assert task.subgoals(w) == [True, True]
    for kw, pred in ((dict(dis=0.199), None), (dict(dis=0.201), "near_pot"), (dict(dis=-0.15), "on_start_side"),
                     (dict(dy=0.034), None), (dict(dy=-0.036), "aligned_with_pot"),
                     (dict(tilt=np.radians(14), yaw=0.0), None), (dict(tilt=np.radians(16), yaw=0.0), "can_upright"),
                     (dict(dz=0.001), None), (dict(dz=0.0015), "set_down")):
        _placed(inst, w, **kw)
        ev = v.evaluate(w)
        if pred is None:
            assert ev.success, (kw, ev)
        else:
            assert not ev.success and ev.predicates[pred] is False, (kw, ev)
    # held above the right spot: beside the pot, not set down
    _placed(inst, w, dz=0.05)
    assert task.subgoals(w) == [True, False]
    _placed(inst, w)
    w.grip[inst.info["arm"]] = 0.8  # must be strictly above 0.8
    ev = v.evaluate(w)
    assert not ev.success and ev.predicates["grippers_open"] is False
    assert task.subgoals(w) == [True, True]  # the catalog's subgoals leave the grippers out
    # lying on its side (axis horizontal) beside the pot
    w.grip[inst.info["arm"]] = 1.0
    _placed(inst, w, tilt=np.pi / 2)
    assert v.evaluate(w).predicates["can_upright"] is False


def test_move_can_pot_euler_matches_transforms3d_convention():
    from cab_core.geometry import euler_quat
    from cab_suite_codeaction.tasks.move_can_pot import euler_sxyz

    rng = np.random.default_rng(0)
    for _ in range(50):
        a = rng.uniform(-1.4, 1.4, 3)
        # euler_quat composes extrinsic x, y, z: R = Rz Ry Rx, exactly what quat2euler('sxyz') inverts
        assert np.allclose(euler_sxyz(euler_quat(*a)), a, atol=1e-9)


# --- with the SAPIEN backend (physics only) ----------------------------------------------------------
@pytest.mark.sim
@pytest.mark.parametrize("name", NAMES)
def test_sim_initial_scene_settles_and_fails(name):
    with sh.sapien_world(TASKS[name]) as (sim, emb, inst):
        sh.check_settled_scene_fails(TASKS[name], sim, emb, inst, 250)
