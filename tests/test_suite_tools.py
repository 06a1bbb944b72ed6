"""The tool-use tasks (click_bell, press_stapler, scan_object): seeded layouts within the FACTS
ranges, generated assets, verifiers that reject the settled initial scene (SAPIEN) and accept
hand-built success states.

The contract every task keeps (catalog entry, deterministic JSON builds, distinct seeded layouts, a
verifier that rejects every initial layout, catalog checkpoints) is checked in test_suite_tasks.py.
"""
from __future__ import annotations

import numpy as np
import pytest
import suite_helpers as sh
from suite_helpers import TASKS, FakeWorld, _cache, task_and_verifier  # noqa: F401 (_cache: autouse)

from cab_core.contracts.scene import ArticulatedObject
from cab_core.contracts.simulator import Contact
from cab_core.geometry import axis_angle_quat, quat_to_mat, transform_point
from cab_core.kits.scene import yaw_of
from cab_suite_codeaction import assets_tools as at

NAMES = ("click_bell", "press_stapler", "scan_object")


# --- layouts ----------------------------------------------------------------------------------------
def test_click_bell_layouts(task_builds):
    task = TASKS["click_bell"]
    models = set()
    for inst in task_builds[task.name]:
        bell = inst.scene.body("bell")
        assert bell.kind == "static"
        x, y, z = bell.pose[:3]
        assert -0.25 <= x <= 0.25 and abs(x) >= 0.05 and -0.2 <= y <= 0.0 and z == pytest.approx(0.74)
        assert np.allclose(bell.pose[3:], (1, 0, 0, 0))
        b = inst.info["bell"]
        models.add(b["model_id"])
        assert inst.info["side_arm"] == ("left" if x < 0 else "right")
        assert 0.06 <= b["height"] <= 0.10 and 0.04 <= b["radius"] <= 0.055
        assert b["contact_points"][0] == [0.0, 0.0, pytest.approx(b["height"])]  # top centre
    assert models == {0, 1}


def test_press_stapler_layouts_and_urdf(task_builds):
    task = TASKS["press_stapler"]
    models, yaws = set(), []
    for inst in task_builds[task.name]:
        (st,) = inst.scene.articulations
        assert isinstance(st, ArticulatedObject) and st.fix_root and st.qpos == (0.0,)
        x, y, z = st.pose[:3]
        assert -0.2 <= x <= 0.2 and -0.1 <= y <= 0.05 and z == pytest.approx(0.74)
        assert np.allclose(quat_to_mat(st.pose[3:])[:, 2], (0, 0, 1))  # heading only
        yaws.append(yaw_of(st.pose[3:]))
        s = inst.info["stapler"]
        models.add(s["model_id"])
        sh.check_urdf_hinge(st.urdf, (s["base_link"], s["arm_link"]), s["hinge_joint"], s["hinge_limits"],
                         s["hinge_point_base"])
        # the press point is on the cover's top, in front of the hinge, behind the nose
        L, W, H = s["size"]
        px, py, pz = np.add(s["hinge_point_base"], s["contact_points_arm"][2])
        assert 0 < px < L / 2 and py == 0 and pz == pytest.approx(H)
        assert 0.12 <= L <= 0.18 and 0.03 <= W <= 0.05 and 0.035 <= H <= 0.06
    assert len(models) >= 5
    assert max(yaws) - min(yaws) > 3.0


def test_scan_object_layouts(task_builds):
    task = TASKS["scan_object"]
    sides, scanners, boxes = set(), set(), set()
    for inst in task_builds[task.name]:
        info = inst.info
        sc, bx = inst.scene.body("scanner"), inst.scene.body("tea_box")
        assert sc.kind == bx.kind == "dynamic" and 0.1 <= sc.mass <= 0.25 and 0.05 <= bx.mass <= 0.2
        s_side = info["scanner_side"]
        sides.add(s_side)
        assert info["object_side"] != s_side and info["scanner_arm"] == s_side and info["object_arm"] != s_side
        sx, sy = sc.pose[:2]
        ox, oy = bx.pose[:2]
        lo, hi = (-0.25, -0.05) if s_side == "left" else (0.05, 0.25)
        assert lo <= sx <= hi and -0.15 <= sy <= -0.05
        lo, hi = (0.05, 0.25) if s_side == "left" else (-0.25, -0.05)
        assert lo <= ox <= hi and -0.2 <= oy <= 0.0
        for b in (sc, bx):
            assert np.allclose(quat_to_mat(b.pose[3:])[:, 2], (0, 0, 1)) and abs(yaw_of(b.pose[3:])) <= 1.2 + 1e-9
        size = info["object"]["size"]
        assert bx.pose[2] == pytest.approx(0.74 + size[2] / 2, abs=5e-4) and sc.pose[2] == pytest.approx(0.74, abs=5e-4)
        assert size[1] <= 0.07 and size[0] / 2 + 0.015 < 0.07  # graspable across y; scannable along x
        g = at.scanner_geometry(at.SCANNER_VARIANTS[info["scanner"]["model_id"]])
        box_rects = [((0.0, 0.0), (size[0] / 2, size[1] / 2), 0.0)]
        assert at.footprint_distance(g["rects"], sc.pose, box_rects, bx.pose) >= 0.03
        scanners.add(info["scanner"]["model_id"])
        boxes.add(info["object"]["model_id"])
    assert sides == {"left", "right"} and len(scanners) >= 4 and len(boxes) >= 5


def test_scanner_geometry():
    for v in at.SCANNER_VARIANTS:
        g = at.scanner_geometry(v)
        # the window is the front of the footprint, the grasp point on the handle, behind and aside
        assert g["window_point"][0] == pytest.approx(max(r[0][0] + r[1][0] for r in g["rects"][:2]))
        gp = g["grasp_point"]
        assert gp[0] < g["window_point"][0] - 0.05 and gp[1] < g["window_point"][1] - 0.02
        assert 0.028 <= v.handle_width <= 0.036 and 0.04 <= v.thickness <= 0.05
        assert max(g["extent"]) <= 0.16


def test_stapler_hinge_presses_the_nose_down():
    v = at.STAPLER_VARIANTS[0]
    g = at.stapler_geometry(v)
    rest = at.stapler_arm_point(v, 0.0, g["press_point_arm"])
    pressed = at.stapler_arm_point(v, at.STAPLER_PRESS_TRAVEL, g["press_point_arm"])
    assert 0.003 < rest[2] - pressed[2] < 0.012


# --- verifiers on hand-built states -------------------------------------------------------------
def test_click_bell_verifier():
    task, inst, v = task_and_verifier("click_bell")
    assert v.scoring == "latch" and v.guarded_objects == ()
    w = FakeWorld(inst)
    arm = inst.info["side_arm"]
    other = "left" if arm == "right" else "right"
    knob = transform_point(inst.info["bell"]["pose"], inst.info["bell"]["contact_points"][0])
    ev = v.evaluate(w)
    assert not ev.success and ev.predicates == {"side_gripper_closed": False, "knob_contact": False}
    w.contact_list = [Contact("bell", "robot/finger", 0.01, tuple(knob + [0.02, -0.02, 0.0]))]
    assert v.evaluate(w).predicates == {"side_gripper_closed": False, "knob_contact": True}
    w.grip[other] = 0.0  # the other arm's gripper does not count
    assert not v.evaluate(w).success
    w.grip[arm] = 0.19
    assert v.evaluate(w).success and task.subgoals(w) == [True]
    # off the top centre, or no contact point / no impulse
    w.contact_list = [Contact("bell", "robot/finger", 0.01, tuple(knob + [0.026, 0.0, 0.0]))]
    assert not v.evaluate(w).success
    w.contact_list = [Contact("bell", "robot/finger", 0.01, tuple(knob - [0.0, 0.0, 0.031]))]
    assert not v.evaluate(w).success
    w.contact_list = [Contact("bell", "robot/finger", 0.0, tuple(knob))]
    assert not v.evaluate(w).success
    w.contact_list = [Contact("bell", "table", 0.01, tuple(knob))]  # not a gripper
    assert not v.evaluate(w).success


def test_click_bell_gripper_bodies_from_the_embodiment():
    class Spec:
        def __init__(self, ee, fingers):
            self.ee_link = ee
            self.gripper = type("G", (), {"finger_links": fingers})()

    emb = type("E", (), {"arms": {"left": Spec("l6", ("l7", "l8")), "right": Spec("r6", ("r7", "r8"))}})()
    task = TASKS["click_bell"]
    inst = task.build(0, emb)
    assert inst.info["gripper_bodies"] == {"left": ["robot/l6", "robot/l7", "robot/l8"],
                                           "right": ["robot/r6", "robot/r7", "robot/r8"]}
    v = task.verifier(inst)
    w = FakeWorld(inst, grip=0.0)
    knob = transform_point(inst.info["bell"]["pose"], inst.info["bell"]["contact_points"][0])
    w.contact_list = [Contact("bell", "robot/r7", 0.01, tuple(knob))]
    assert v.evaluate(w).success
    w.contact_list = [Contact("bell", "robot/r3", 0.01, tuple(knob))]  # a forearm link is not a gripper
    assert not v.evaluate(w).success


def test_press_stapler_verifier():
    task, inst, v = task_and_verifier("press_stapler")
    assert v.scoring == "latch" and v.guarded_objects == ()
    w = FakeWorld(inst)
    s = inst.info["stapler"]
    press = np.asarray(s["press_point_world_rest"])
    assert not v.evaluate(w).success
    w.contact_list = [Contact("robot/finger", "stapler/arm", 0.01, tuple(press + [0.029, -0.029, 0.0]))]
    ev = v.evaluate(w)
    assert ev.success and ev.predicates == {"press_contact": True} and task.subgoals(w) == [True]
    w.contact_list = [Contact("robot/finger", "stapler/arm", 0.01, tuple(press + [0.0, 0.0, 0.031]))]
    assert not v.evaluate(w).success
    w.contact_list = [Contact("robot/finger", "table", 0.01, tuple(press))]
    assert not v.evaluate(w).success
    # the press point follows the arm: pressed down, a contact at the resting point is 7 mm above it
    w.qpositions["stapler"] = np.array([s["hinge_limits"][1]])
    ref = task.spatial_checkpoints(inst.info)[0].reference(w)
    assert ref[2] < press[2] + 0.0354 - 0.003


def _scan_pose(inst, d=0.05, lateral=(0.0, 0.0), yaw=0.0):
    """The scanner posed with its beam (heading ``yaw``) on the box centre, window ``d`` short of
    it, shifted sideways by ``lateral`` (world y, z)."""
    s = inst.info["scanner"]
    box_c = np.asarray(inst.info["object"]["pose"][:3])
    q = axis_angle_quat([0, 0, 1], yaw)
    beam = quat_to_mat(q)[:, 0]
    win = box_c - d * beam + [0.0, lateral[0], lateral[1]]
    pos = win - quat_to_mat(q) @ np.asarray(s["functional_point"][:3])
    return np.concatenate([pos, q])


def test_scan_object_verifier():
    task = TASKS["scan_object"]
    inst = task.build(task.info.seed, None)
    v = task.verifier(inst)
    assert v.scoring == "final" and set(v.guarded_objects) == {"scanner", "tea_box"}
    w = FakeWorld(inst, grip=0.0)
    ev = v.evaluate(w)
    assert not ev.success and ev.predicates["object_on_beam"] is False
    w.poses["scanner"] = _scan_pose(inst, 0.05)
    ev = v.evaluate(w)
    assert ev.success and ev.values["beam_distance"] == pytest.approx(0.05, abs=1e-5)
    assert ev.predicates == {"object_on_beam": True, "scan_distance": True, "grippers_closed": True}
    assert task.subgoals(w) == [True, True]
    w.poses["scanner"] = _scan_pose(inst, 0.05, yaw=2.5)  # any heading
    assert v.evaluate(w).success
    w.poses["scanner"] = _scan_pose(inst, 0.05, (0.024, -0.024))
    assert v.evaluate(w).success
    w.poses["scanner"] = _scan_pose(inst, 0.05, (0.026, 0.0))
    assert v.evaluate(w).predicates["object_on_beam"] is False and task.subgoals(w) == [False, False]
    w.poses["scanner"] = _scan_pose(inst, 0.069)
    assert v.evaluate(w).success
    w.poses["scanner"] = _scan_pose(inst, 0.071)
    ev = v.evaluate(w)
    assert not ev.success and ev.predicates["object_on_beam"] and not ev.predicates["scan_distance"]
    assert task.subgoals(w) == [True, False]
    w.poses["scanner"] = _scan_pose(inst, -0.03)  # the box behind the window
    assert not v.evaluate(w).predicates["scan_distance"]
    w.poses["scanner"] = _scan_pose(inst, 0.05)
    w.grip["left"] = 0.2  # must be strictly below 0.2
    ev = v.evaluate(w)
    assert not ev.success and ev.predicates["grippers_closed"] is False
    # the scan-alignment checkpoint reference follows the box
    rule = task.spatial_checkpoints(inst.info)[2]
    assert rule.prerequisites == (0, 1)
    r0 = np.asarray(rule.reference(w))
    w.poses["tea_box"][:3] += [0.1, 0.05, 0.2]
    assert np.allclose(np.asarray(rule.reference(w)) - r0, [0.1, 0.05, 0.2])
    # guard
    assert v.guard(w) == {"scanner_on_table": True, "tea_box_on_table": True}
    w.poses["tea_box"][2] = 0.6
    assert v.guard(w)["tea_box_on_table"] is False


# --- with the SAPIEN backend --------------------------------------------------------------------
@pytest.mark.sim
@pytest.mark.parametrize("name", NAMES)
def test_sim_initial_scene_settles_and_fails(name):
    with sh.sapien_world(TASKS[name]) as (sim, emb, inst):
        sh.check_settled_scene_fails(TASKS[name], sim, emb, inst, 100)
        for a in inst.scene.articulations:
            assert np.allclose(sim.get_object_qpos(a.name), a.qpos or (), atol=1e-3)
