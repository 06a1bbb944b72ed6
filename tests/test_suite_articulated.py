"""The ``articulated`` group of the CodeActionBench suite: open_laptop_setup_arm and
place_dual_shoes. Deterministic seeded layouts within the FACTS ranges, consistent privileged
facts (URDF frames, functional points), verifiers that reject the initial scene and accept
hand-built success states, and what the spatial checkpoints refer to.

Verifiers are exercised through :class:`FakeWorld` (plain data, no simulator); the ``sim`` tests use
the project's SAPIEN backend when it and the embodiment are installed.

The contract every task keeps (catalog entry, deterministic JSON builds, distinct seeded layouts, a
verifier that rejects every initial layout, catalog checkpoints) is checked in test_suite_tasks.py.
"""
from __future__ import annotations

import numpy as np
import pytest
import suite_helpers as sh
from suite_helpers import SEEDS, LaptopWorld, _cache  # noqa: F401 (_cache: autouse)

from cab_core.contracts.scene import ArticulatedObject
from cab_core.geometry import quat_to_mat, transform_point
from cab_core.kits.scene import yaw_of
from cab_suite_codeaction.assets_articulated import lid_rotation
from cab_suite_codeaction.tasks import open_laptop_setup_arm as laptop_mod
from cab_suite_codeaction.tasks import place_dual_shoes as shoes_mod

LAPTOP = laptop_mod.TASK()


FakeWorld = LaptopWorld  # the shared stand-in, which also serves the laptop's lid link pose


# =================================================================================================
# open_laptop_setup_arm
# =================================================================================================
def test_laptop_layouts_and_urdf(task_builds):
    layouts, models = set(), set()
    for inst in task_builds["open_laptop_setup_arm"]:
        (lap,) = inst.scene.articulations
        m = inst.info["laptop"]
        assert isinstance(lap, ArticulatedObject) and lap.fix_root and lap.joint_friction > 0
        x, y, z = lap.pose[:3]
        assert -0.05 <= x <= 0.05 and -0.1 <= y <= 0.05 and z == pytest.approx(0.74)
        assert np.allclose(quat_to_mat(lap.pose[3:])[:, 2], (0, 0, 1))  # yaw only
        assert abs(yaw_of(lap.pose[3:])) <= np.pi / 3 + 1e-9
        lo, hi = m["lid_limits"]
        assert lap.qpos == pytest.approx((lo + 0.2 * (hi - lo),))
        assert m["success_qpos"] == pytest.approx(lo + 0.4 * (hi - lo))
        assert inst.info["suggested_arm"] == ("right" if yaw_of(lap.pose[3:]) > 0 else "left")
        sh.check_urdf_hinge(lap.urdf, (m["base_link"], m["lid_link"]), m["lid_joint"], (lo, hi), m["hinge_point_base"],
                         m["hinge_axis_base"])
        w, d, t = m["size"]
        assert 0.28 <= w <= 0.36 and 0.20 <= d <= 0.24 and 0.012 <= t <= 0.025
        assert m["edge_point_lid"][1] == pytest.approx(-d)  # the lid's front edge
        models.add(m["model_id"])
        layouts.add(tuple(np.round(lap.pose, 6)))
    assert len(layouts) == len(SEEDS) and len(models) >= 3


def test_laptop_lid_opens_upward_and_faces_the_robot():
    m = LAPTOP.build(0, None).info["laptop"]
    edge0 = lid_rotation(0.0) @ np.asarray(m["edge_point_lid"])
    edge1 = lid_rotation(1.0) @ np.asarray(m["edge_point_lid"])
    assert edge1[2] > edge0[2] + 0.1 and edge0[1] < 0  # front edge rises; the front is -y_base
    # at yaw 0 the front (base -y) faces the robot (world -y)
    assert np.allclose(m["front_dir_world"], [np.sin(m["yaw"]), -np.cos(m["yaw"]), 0], atol=1e-6)


def _laptop_success(inst, w, frac=0.6, tcp_offset=(0.0, -0.05, 0.0), arm="right"):
    lo, hi = inst.info["laptop"]["lid_limits"]
    w.qpositions["laptop"] = np.array([lo + frac * (hi - lo)])
    v = LAPTOP.verifier(inst)
    edge = v.edge_point(w)
    w.tcp[arm][:3] = edge + np.asarray(tcp_offset)
    return v


def test_laptop_verifier(task_builds):
    for inst in task_builds["open_laptop_setup_arm"]:
        ev = LAPTOP.verifier(inst).evaluate(FakeWorld(inst))
        assert ev.success is False and ev.predicates == {"lid_open": False, "gripper_at_lid_edge": False}
    inst = LAPTOP.build(0, None)
    w = FakeWorld(inst)
    v = _laptop_success(inst, w)
    assert v.guarded_objects == ()
    ev = v.evaluate(w)
    assert ev.success and ev.predicates == {"lid_open": True, "gripper_at_lid_edge": True}
    assert ev.values["lid_fraction"] == pytest.approx(0.6)
    # either arm counts (the benchmark's adaptation)
    w = FakeWorld(inst)
    assert _laptop_success(inst, w, arm="left").evaluate(w).success
    # thresholds: 40% of the range, 0.1 m from the edge
    w = FakeWorld(inst)
    assert _laptop_success(inst, w, frac=0.401).evaluate(w).success
    w = FakeWorld(inst)
    ev = _laptop_success(inst, w, frac=0.399).evaluate(w)
    assert ev.predicates == {"lid_open": False, "gripper_at_lid_edge": True}
    w = FakeWorld(inst)
    ev = _laptop_success(inst, w, tcp_offset=(0.0, -0.101, 0.0)).evaluate(w)
    assert ev.predicates == {"lid_open": True, "gripper_at_lid_edge": False}


def test_laptop_checkpoints():
    inst = LAPTOP.build(0, None)
    w = FakeWorld(inst)
    assert LAPTOP.subgoals(w) == [False, False]
    assert len(LAPTOP.subgoals(w)) == LAPTOP.info.subgoals.__len__() == 2
    _laptop_success(inst, w, frac=0.6, tcp_offset=(0.0, 0.0, 0.2))
    assert LAPTOP.subgoals(w) == [True, False]
    _laptop_success(inst, w)
    assert LAPTOP.subgoals(w) == [True, True]
    rules = LAPTOP.spatial_checkpoints(inst.info)
    assert rules[1].prerequisites == (0,)
    # the approach reference sits in front of / under the lid's front edge at the start
    w = FakeWorld(inst)
    edge = LAPTOP.verifier(inst).edge_point(w)
    ref = np.asarray(rules[0].reference(w))
    assert np.linalg.norm(ref - edge) < 0.08 and ref[2] < edge[2]
    # the open reference is above the closed lid's edge height: the lid has been lifted
    assert np.asarray(rules[1].reference(w))[2] > edge[2] + 0.05


# --- with the SAPIEN backend --------------------------------------------------------------------
@pytest.mark.sim
def test_sim_laptop_frames_hinge_and_verdicts():
    with sh.sapien_world(LAPTOP) as (sim, emb, inst):
        m = inst.info["laptop"]
        sim.step(LAPTOP.settle_steps())
        w = sh.world_view(sim, emb, inst)
        v = LAPTOP.verifier(inst)
        assert v.evaluate(w).success is False
        q0 = m["initial_qpos"]
        assert float(w.qpos("laptop")[0]) == pytest.approx(q0, abs=0.01)  # the hinge holds the lid
        # the simulator's lid link is where the documented frames put it
        fake = FakeWorld(inst)
        fake.qpositions["laptop"] = np.array([float(w.qpos("laptop")[0])])
        assert np.allclose(w.link_pose("laptop", m["lid_link"])[:3], fake.link_pose("laptop", m["lid_link"])[:3],
                           atol=1e-3)
        # open the lid to 60% of its range: the friction hinge holds it there
        lo, hi = m["lid_limits"]
        sim.set_object_qpos("laptop", [lo + 0.6 * (hi - lo)])
        sim.step(250)
        assert float(w.qpos("laptop")[0]) == pytest.approx(lo + 0.6 * (hi - lo), abs=0.01)
        ev = v.evaluate(w)
        assert ev.predicates == {"lid_open": True, "gripper_at_lid_edge": False}
        # bring the laptop (its root is fixed, but can be teleported) so that the lid edge is 5 cm
        # in front of the right gripper
        shift = w.tcp_pose("right")[:3] - v.edge_point(w) + np.array([0.0, 0.05, 0.0])
        pose = np.asarray(w.pose("laptop"), float)
        pose[:3] += shift
        sim.set_object_pose("laptop", pose)
        sim.step(2)
        ev = v.evaluate(w)
        assert ev.success, ev
        # the verifier measures the edge where the world has it (the teleported lid settles on its
        # hinge in those 2 steps: 5.0-5.6 cm away, as the contact generation has it)
        gap = float(np.linalg.norm(w.tcp_pose("right")[:3] - v.edge_point(w)))
        assert ev.values["tcp_to_edge_right"] == pytest.approx(gap, abs=1e-6)
        assert ev.values["tcp_to_edge_right"] == pytest.approx(0.05, abs=0.01)
        assert LAPTOP.subgoals(w) == [True, True]


# =================================================================================================
# place_dual_shoes
# =================================================================================================
SHOES = shoes_mod.TASK()


def _footprint(inst, side):
    from cab_suite_codeaction.assets_articulated import SHOE_STYLES, shoe_outline

    style = SHOE_STYLES[inst.info["style_id"]]
    o = shoe_outline(style, side)
    local = np.stack([o[:, 1], np.zeros(len(o)), o[:, 0]], axis=1)  # design (X, Y) -> body (z, x)
    pose = np.asarray(inst.scene.body(f"{side}_shoe").pose)
    return np.array([transform_point(pose, p) for p in local])


def test_shoes_layouts(task_builds):
    layouts, styles = set(), set()
    for inst in task_builds["place_dual_shoes"]:
        sc = inst.scene
        assert sc.body("table").pose[2] + 0.025 == pytest.approx(0.64)  # table_z_bias -0.1
        box = sc.body("shoe_box")
        assert box.kind == "static" and np.allclose(box.pose, (0.0, -0.13, 0.64, 1, 0, 0, 0))
        half = np.asarray(inst.info["box"]["outer_size"][:2]) / 2
        for side, (lo, hi) in (("left", (-0.3, -0.2)), ("right", (0.2, 0.3))):
            b = sc.body(f"{side}_shoe")
            x, y, z = b.pose[:3]
            assert b.kind == "dynamic" and 0.1 <= b.mass <= 0.3
            assert lo <= x <= hi and -0.1 <= y <= 0.05 and np.hypot(x, y) >= 0.15
            assert z == pytest.approx(0.641)
            r = quat_to_mat(b.pose[3:])
            assert np.allclose(r[:, 1], (0, 0, 1), atol=1e-9)  # upright: the shoe's +y is world up
            foot = _footprint(inst, side)[:, :2]
            d = np.maximum(np.abs(foot - box.pose[:2]) - half, 0.0)
            assert np.min(np.hypot(d[:, 0], d[:, 1])) >= 0.035 - 1e-9
            assert np.min(foot[:, 0] if side == "right" else -foot[:, 0]) > 0.0  # on its own side
        styles.add(inst.info["style_id"])
        layouts.add(tuple(np.round(np.concatenate([sc.body("left_shoe").pose, sc.body("right_shoe").pose]), 6)))
    assert len(layouts) == len(SEEDS) and len(styles) >= 3
    # headings cover all directions
    heads = [i.info["shoes"][side]["toe_heading"] for i in task_builds["place_dual_shoes"] for side in ("left", "right")]
    assert max(heads) > 2.0 and min(heads) < -2.0 and any(abs(h) < 1.0 for h in heads)


def test_shoe_geometry_fits_the_box_and_the_gripper():
    from cab_suite_codeaction.assets_articulated import SHOE_STYLES, shoe_geometry, shoe_outline

    info = SHOES.build(6, None).info
    inner_l, inner_w, _ = info["box"]["inner_size"]
    gap = info["places"]["right"][1] - info["places"]["left"][1]
    assert gap == pytest.approx(0.08)
    for style in SHOE_STYLES:
        g = shoe_geometry(style)
        assert 0.17 <= g["length"] <= 0.21 and g["length"] < inner_l - 0.08  # room for the fingers
        assert g["width"] < gap - 0.01 and gap + g["width"] < inner_w - 0.02  # side by side in the box
        # the pinch point is on the heel counter's flat back, inside its thickness
        assert g["heel_wall_center"][2] == pytest.approx(-g["length"] / 2 + g["wall_thickness"] / 2)
        for foot in ("left", "right"):
            o = shoe_outline(style, foot)
            assert np.min(o[:, 0]) == pytest.approx(-g["length"] / 2)
            assert np.max(o[:, 0]) == pytest.approx(g["length"] / 2)
            assert np.max(np.abs(o[:, 1])) <= g["width"] / 2 + 0.002
    grasp = np.asarray(info["shoe"]["grasp_tcp_point"])
    assert info["shoe"]["sole_thickness"] + 0.035 < grasp[1] < info["shoe"]["heel_height"] + 0.035


def _in_box(inst, w, swap=False, d_left=(0, 0, 0), d_right=(0, 0, 0), q_left=None):
    places = inst.info["places"]
    z = inst.info["box"]["pose"][2] + inst.info["floor_offset"]
    q = np.asarray(inst.info["target_quat"])
    a, b = ("right", "left") if swap else ("left", "right")
    w.poses["left_shoe"] = np.array([*places[a], z, *(q if q_left is None else q_left)]) + np.r_[d_left, 0, 0, 0, 0]
    w.poses["right_shoe"] = np.array([*places[b], z, *q]) + np.r_[d_right, 0, 0, 0, 0]


def test_shoes_verifier(task_builds):
    from cab_core.geometry import axis_angle_quat, quat_mul

    for inst in task_builds["place_dual_shoes"]:
        ev = SHOES.verifier(inst).evaluate(FakeWorld(inst))
        assert ev.success is False and ev.predicates["assignment_xy"] is False
    inst = SHOES.build(6, None)
    v = SHOES.verifier(inst)
    assert set(v.guarded_objects) == {"left_shoe", "right_shoe"}
    w = FakeWorld(inst)
    _in_box(inst, w)
    ev = v.evaluate(w)
    assert ev.success and ev.predicates == {"assignment_xy": True, "heights": True, "orientations": True,
                                            "grippers_open": True}
    assert ev.values["swapped_assignment"] == 0.0
    _in_box(inst, w, swap=True)  # the benchmark accepts the swapped pairing
    ev = v.evaluate(w)
    assert ev.success and ev.values["swapped_assignment"] == 1.0
    _in_box(inst, w, d_left=(0.049, -0.049, 0.029))
    assert v.evaluate(w).success
    _in_box(inst, w, d_left=(0.051, 0.0, 0.0))
    assert v.evaluate(w).predicates["assignment_xy"] is False
    _in_box(inst, w, d_right=(0.0, 0.0, 0.031))
    ev = v.evaluate(w)
    assert not ev.success and ev.predicates["heights"] is False and ev.predicates["assignment_xy"] is True
    # both shoes at the same place is not an assignment
    _in_box(inst, w, d_right=(0.0, -0.08, 0.0))
    assert v.evaluate(w).predicates["assignment_xy"] is False
    # orientation: a 0.2 rad turn about the vertical is within 0.07 per component, 0.35 rad is not;
    # the toe pointing right (a half turn) is wrong
    q = np.asarray(inst.info["target_quat"])
    for ang, ok in ((0.2, True), (-0.2, True), (0.35, False), (np.pi, False)):
        _in_box(inst, w, q_left=quat_mul(axis_angle_quat([0, 0, 1], ang), q))
        assert v.evaluate(w).predicates["orientations"] is ok, ang
    _in_box(inst, w, q_left=-q)  # sign-normalised
    assert v.evaluate(w).success
    _in_box(inst, w)
    w.grip["right"] = 0.8
    ev = v.evaluate(w)
    assert not ev.success and ev.predicates["grippers_open"] is False


def test_shoes_checkpoints():
    inst = SHOES.build(6, None)
    w = FakeWorld(inst)
    assert SHOES.subgoals(w) == [False, False]
    assert len(SHOES.subgoals(w)) == len(SHOES.info.subgoals) == 2
    _in_box(inst, w, d_left=(0, 0, 0.05))  # above the box: xy assignment only
    assert SHOES.subgoals(w) == [True, False]
    _in_box(inst, w)
    w.grip["left"] = 0.0  # subgoals ignore the grippers
    assert SHOES.subgoals(w) == [True, True]
    rules = SHOES.spatial_checkpoints(inst.info)
    assert rules[2].prerequisites == (0, 1)
    w = FakeWorld(inst)
    for rule, side in zip(rules[:2], ("left", "right")):
        ref = np.asarray(rule.reference(w))
        pose = w.poses[f"{side}_shoe"]
        assert np.hypot(*(ref[:2] - pose[:2])) == pytest.approx(inst.info["shoe"]["length"] / 2, abs=0.01)
        assert rule.test(np.zeros(3)) and not rule.test(np.array([0.0, 0.0, 7.0]))
    ref = np.asarray(rules[2].reference(w))
    # the release reference: over the box's heel end, just above the floor
    assert 0.0 < ref[0] < 0.15 and ref[1] == pytest.approx(-0.13) and 0.64 + 0.01 + 0.035 < ref[2] < 0.64 + 0.12


@pytest.mark.sim
def test_sim_shoes_settle_and_rest_in_the_box():
    with sh.sapien_world(SHOES) as (sim, emb, inst):
        w, v, before = sh.check_settled_scene_fails(SHOES, sim, emb, inst, 250)
        for n in ("left_shoe", "right_shoe"):
            assert abs(before[n][2] - 0.64) < 2e-3  # the sole stands on the lowered table
        # both shoes into the box, toes left: they stand side by side on its floor
        fake = FakeWorld(inst)
        _in_box(inst, fake)
        for n in ("left_shoe", "right_shoe"):
            sim.set_object_pose(n, fake.poses[n] + np.r_[0, 0, 0.002, 0, 0, 0, 0])
        sim.step(250)
        ev = v.evaluate(w)
        assert ev.success, ev
        assert abs(ev.values["left_shoe_dz"]) < 0.002 and abs(ev.values["right_shoe_dz"]) < 0.002
